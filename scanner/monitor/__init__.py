"""The cell monitor's perception, from a static stereo rig watching the robot cell.

stereo_point  the rig's model (intrinsics, rectification, X_WS): pixels -> points in the world
detector      intrusion detection: background model + three-frame differencing, robot masked,
              candidates confirmed in 3D inside the monitored volume
ee_tracker    the end effector tracked by three-frame differencing and a constant-velocity
              Kalman filter, compared with where forward kinematics says it is
"""
