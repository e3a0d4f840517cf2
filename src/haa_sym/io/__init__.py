"""Files, progress and figures (layer 2): all-or-nothing outputs, npz/JSON/CSV formats, the
memory budget, progress bars, provenance and the plotting layer (which draws plain result data)."""
