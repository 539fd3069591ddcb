"""Terrain fused over the flight (METHOD 2.3.6): a world-fixed landing map that gains evidence frame by frame.

``grid``: the cells (a window of them that follows the UAV) and the per-cell Kalman update of one frame's
measurements; ``measure``: one frame's depth -> per-cell height measurements with their noise; ``verdict``:
the four maps, score, mask and safe / unsafe / undecided per cell on the fused heights; ``advice``: what
would decide the undecided ground near the best candidates.
"""
