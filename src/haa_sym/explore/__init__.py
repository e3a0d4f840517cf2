"""The interactive gain explorer (``haa-sym explore``): :mod:`haa_sym.explore.state`, the view
state and its computations as plain data (no web framework), and :mod:`haa_sym.explore.app`, the
Panel page that draws them (the optional extra ``haa_sym[explore]``)."""
