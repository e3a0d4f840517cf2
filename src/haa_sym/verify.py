"""``python -m haa_sym.verify``: the symbolic checks of :mod:`haa_sym.check.verify` (the paper's
equations, or any actuator file's chain identities with ``--params``)."""
from haa_sym.check.verify import main

if __name__ == "__main__":
    raise SystemExit(main())
