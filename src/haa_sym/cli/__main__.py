"""``python -m haa_sym.cli``."""
from haa_sym.cli import entry

if __name__ == "__main__":
    entry()
