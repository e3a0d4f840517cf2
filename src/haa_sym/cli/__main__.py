"""``python -m haa_sym.cli``."""
import sys

from haa_sym.cli import main

if __name__ == "__main__":
    sys.exit(main())
