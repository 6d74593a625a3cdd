"""Robot arms behind one interface, `Arm` (arm.py): joints, limits, the Drake model and its
flange, FK and IK. The RX60 stands behind it with its closed-form kinematics (rx60.py); any other
serial arm is described by an arm file (YAML naming a URDF, SDF or xacro model, its flange link,
base pose and what limits the model lacks) and solved numerically (`load_arm`). Adding an arm is
adding a file; default.py names the arm used when none is."""
