"""`python -m motor_id.cli`: the `motor-id` command."""

import sys

from motor_id.cli import main

sys.exit(main())
