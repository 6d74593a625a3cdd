"""Robot arms described by files: an arm file (YAML) names a URDF, SDF or xacro model, its flange
link, base pose and what limits the model lacks; `load_arm` turns it into an `Arm` with forward
kinematics and numerical inverse kinematics. Adding an arm is adding a file."""
