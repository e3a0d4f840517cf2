"""Exact boundaries in the gain plane by the parameter-space method: stability, phase margin,
passivity, and the maps classified from them."""
