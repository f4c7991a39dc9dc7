"""Position control of a PMA-driven 1-DOF manipulator: the seed papers' cascade controllers.

Uses the rig (:mod:`pmalab.rig.manipulator`, the simulated one in
:mod:`pmalab.rig.sim.manipulator`), acquisition's safety monitor and identify's laws;
nothing in rig, acquisition, identify or reports imports this package.
"""
