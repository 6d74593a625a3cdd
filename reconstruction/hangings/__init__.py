"""Several hangings of one object into one frame: each pass aligned without truth and verified,
then merged."""
