"""An arm nobody ships: a 6R URDF and its arm file written into a test's folder, to show that
adding an arm is writing two files (loaded, solved, planned around and scanned with)."""

from __future__ import annotations

from pathlib import Path

TINY_URDF = """<?xml version="1.0"?>
<robot name="tiny6">
  <link name="base">{base}</link>
  {links}
</robot>
"""
# An anthropomorphic 6R arm with a spherical wrist: a 0.3 m column, a 0.4 m upper arm, a 0.35 m
# forearm and 0.08 m to the flange. Per joint: its origin in the parent link and its axis.
ORIGINS = ("0 0 0.3", "0 0 0", "0 0 0.4", "0 0 0.35", "0 0 0", "0 0 0.08")
AXES = ("0 0 1", "0 1 0", "0 1 0", "0 0 1", "0 1 0", "0 0 1")
# Each link's collision cylinder runs up its own z axis towards the next joint, so that the
# planner has a real body to keep clear of the cell. The cylinders stop short of the joints at
# both ends: Drake filters only a joint's own two bodies, and at the shoulder and the wrist a
# zero-length link puts a third one at the same point (the short wrist link gets none).
LINK_RADIUS_M = 0.035
JOINT_CLEARANCE_M = 0.06


def _cylinder(start_m: float, end_m: float) -> str:
    if end_m <= start_m:
        return ""
    return (
        f'<collision><origin xyz="0 0 {(start_m + end_m) / 2}"/><geometry>'
        f'<cylinder radius="{LINK_RADIUS_M}" length="{end_m - start_m}"/></geometry></collision>'
    )


def tiny_urdf() -> str:
    """The URDF text; one inertia per link so that Drake accepts it."""
    lengths = [float(o.split()[2]) for o in ORIGINS[1:]]
    parts, parent = [], "base"
    for i, (xyz, axis) in enumerate(zip(ORIGINS, AXES), start=1):
        child = f"link{i}"
        body = (
            _cylinder(JOINT_CLEARANCE_M, lengths[i - 1] - JOINT_CLEARANCE_M)
            if i <= len(lengths)
            else ""
        )
        parts.append(
            f'<link name="{child}"><inertial><mass value="1"/>'
            f'<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
            f"{body}</link>"
            f'<joint name="j{i}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
            f'<limit lower="-2.9" upper="2.9" velocity="2.0" effort="10"/></joint>'
        )
        parent = child
    column = float(ORIGINS[0].split()[2])
    base = _cylinder(0.0, column - JOINT_CLEARANCE_M)
    return TINY_URDF.format(base=base, links="\n  ".join(parts))


def write_tiny_arm(folder: Path, **overrides) -> Path:
    """tiny6.urdf and tiny6.yaml in `folder`; `overrides` replace (None: drop) arm-file fields,
    given as YAML text. Returns the arm file's path."""
    (folder / "tiny6.urdf").write_text(tiny_urdf())
    fields = {
        "name": "tiny6",
        "model": "tiny6.urdf",
        "flange_link": "link6",
        "base_pose": "{xyz_m: [0.1, 0.2, 0.0], rpy_rad: [0.0, 0.0, 0.5]}",
        "joint_limits": "{"
        + ", ".join(f"j{i}: {{acceleration_rad_s2: 5.0}}" for i in range(1, 7))
        + "}",
        "accuracy_m": "0.001",
        "repeatability_m": "0.0001",
    }
    fields.update(overrides)
    text = "".join(f"{k}: {v}\n" for k, v in fields.items() if v is not None)
    path = folder / "tiny6.yaml"
    path.write_text(text)
    return path
