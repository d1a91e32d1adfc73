"""`python -m robotsim`: the reference robot-side controller (robotsim/controller.py)."""
import sys

from robotsim.controller import main

sys.exit(main())
