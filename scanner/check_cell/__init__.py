"""`scanner check-cell`: is a real cell ready to scan? Checked without moving the arm."""
