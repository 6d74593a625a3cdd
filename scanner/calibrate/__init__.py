"""`scanner calibrate`: the stereo pair and the hand-eye transform, live, offline or
eye-to-hand; its reports; the calibration file to and from OpenCV and ROS (`scanner export`,
`scanner import-calibration`)."""
