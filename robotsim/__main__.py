"""`python -m shelfpick.robotsim`: the reference robot-side controller (robotsim/controller.py)."""
import sys

from shelfpick.robotsim.controller import main

sys.exit(main())
