"""pmalab: a workbench for pneumatic muscle actuators (PMA, McKibben muscles).

Areas (data flows one way): ``rig`` → ``acquisition`` → HDF5 (``runfile``) → ``identify``
→ ``reports``.  See docs/explanation/physics.md for sign conventions: position x is the contraction in mm
(positive = shorter than nominal), force F is the tension in N.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    #: the installed distribution's version; its one source is pyproject.toml
    __version__: str = version("pmalab")
except PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"
