"""The interfaces a robot and a camera implement (the simulator and real hardware alike)."""
