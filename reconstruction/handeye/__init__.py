"""The hand-eye transform X_FC corrected from the scan itself: a coarse basin search for rough
mounts, AX = XB plus a joint refinement on the clouds, and the convergence diagnosis."""
