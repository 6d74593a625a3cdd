"""Recordings of other systems made into scan directories: the `scanner import-recording`
command (import_command) and the writing of the scan directory (scan_writer); the readers are
in reconstruction.recordings."""
