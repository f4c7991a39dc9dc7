"""pmalab: a workbench for pneumatic muscle actuators (PMA, McKibben muscles).

Areas (data flows one way): ``rig`` → ``acquisition`` → HDF5 (``runfile``) → ``identify``
→ ``reports``.  See docs/explanation/physics.md for sign conventions: position x is the contraction in mm
(positive = shorter than nominal), force F is the tension in N.
"""

#: the version, its one source: pyproject.toml reads it from here (statically, at build time).
#: A literal rather than importlib.metadata's lookup, which costs ~40 ms on every command.
__version__: str = "0.1.0"
