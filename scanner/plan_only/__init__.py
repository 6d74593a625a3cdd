"""`scanner scan --plan-only`: the views, tour and motions planned as a scan would plan them;
nothing moves."""
