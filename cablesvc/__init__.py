"""cablesvc: real-time cable-force prediction with hysteresis for cable-driven parallel robots.

Rooms of the package (each one a folder):

- ``config``      robot definitions and parameter files (pydantic, TOML), no I/O beyond reading them
- ``kinematics``  inverse/forward kinematics, pulleys, structure matrix (pure numpy)
- ``models``      cable force models: linear, polynomial, amplitude-dependent, Bouc-Wen, asymmetric
- ``kernel``      the fixed-time per-tick ``Predictor`` the live service calls
- ``recording``   the recording format (MCAP and CSV) read and written by everything
- ``simulate``    the digital twin that writes recordings, with switchable extra physics
- ``bench``       benchmark commands (``cablesvc bench ...``)
- ``cli``         the one command line, ``cablesvc``
- ``data``        the Bouc-Wen benchmark data (package data; source and licence in its README)

"paper 000", "paper 001" and "paper 002" (and "000 eq 25", "002 Sec 4", ...) in docstrings are
the three papers cited in full in docs/references.md, with their own equation numbers.
"""

__version__ = "0.1.0"
