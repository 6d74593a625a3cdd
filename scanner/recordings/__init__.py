"""Recordings of other systems made into scan directories: the runner of `scanner
import-recording` (import_command; its parser is in scanner/commands) and the writing of the scan
directory (scan_writer); the readers are in reconstruction.recordings."""
