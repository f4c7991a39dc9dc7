"""pmalab: a workbench for pneumatic muscle actuators (PMA, McKibben muscles).

Areas (data flows one way): ``rig`` → ``acquisition`` → HDF5 (``runfile``) → ``identify``
→ ``reports``.  See docs/explanation/physics.md for sign conventions: position x is the contraction in mm
(positive = shorter than nominal), force F is the tension in N.
"""

__version__ = "0.1.0"
