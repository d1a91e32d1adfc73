"""shelfpick: collapse- and collision-aware planning for picking boxes out of cluttered shelves.

The one import package of the distribution. Its parts live in the repository's top-level folders
and are mapped into this namespace by pyproject.toml (`[tool.setuptools.package-dir]`), so that
installing shelfpick beside projects named `console`, `planning`, `perception` or `static`
replaces none of them:

- `shelfpick.perception`: one RGB-D capture -> a scene (front faces, depth unknown);
- `shelfpick.planning`: a scene -> a plan, over sample worlds of what the camera cannot see;
- `shelfpick.console`: the operator console, the robot drivers, the session store, the CLI;
- `shelfpick.robotsim`: the reference robot controller (the other end of the TCP protocol);
- `shelfpick.static`: the shipped weights and demo shelves (package data).
"""
