"""The work of `scanner calibrate`: the stereo pair and the hand-eye transform, live (simulated
or on a driver), offline from recorded images, or eye-to-hand; the stations, the solve, the
reports, their bands and the corner pictures."""
