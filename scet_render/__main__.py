import sys

from scet_render.cli import main

sys.exit(main())
