"""Every `scanner` command, one module each: its parser (registered by `main.py`, kept free of
heavy imports) and its runner (arguments -> configuration -> the work in the concept packages ->
a few printed lines); `arguments.py` holds what several parsers share."""
