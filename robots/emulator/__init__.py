"""Emulators of robot controllers, for testing drivers without the robot."""
