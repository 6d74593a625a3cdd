"""`scanner inspect` on meshes whose truth is known: a partial, noisy model of a part against
the part's reference, moved far away and written in millimetres."""

import json

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from reconstruction.common.transforms import pose_difference
from reconstruction.evaluation.metrics import TriangleSurface
from reconstruction.evaluation.reference_alignment import align_reference, reference_unit
from scanner.commands.main import main


def _part() -> o3d.geometry.TriangleMesh:
    """An asymmetric part (~0.15 m): a block with a post off-centre and a cone on its side."""
    block = o3d.geometry.TriangleMesh.create_box(0.12, 0.08, 0.04)
    post = o3d.geometry.TriangleMesh.create_cylinder(0.012, 0.07, resolution=40)
    post.translate((0.03, 0.02, 0.075))
    cone = o3d.geometry.TriangleMesh.create_cone(0.015, 0.04, resolution=40)
    cone.rotate(Rotation.from_euler("y", 90, degrees=True).as_matrix(), center=(0, 0, 0))
    cone.translate((0.12, 0.05, 0.02))
    part = block + post + cone
    part = part.subdivide_midpoint(3)
    part.translate((0.35, -0.05, 0.95))  # where a model sits in the robot's frame
    part.compute_vertex_normals()
    return part


def _model(part: o3d.geometry.TriangleMesh, noise_m: float, seed: int = 0) -> TriangleSurface:
    """What a scan sees: the part without its top 2 cm, vertices moved along their normals."""
    v = np.asarray(part.vertices)
    t = np.asarray(part.triangles)
    keep = v[t].mean(axis=1)[:, 2] < v[:, 2].max() - 0.02
    offset = np.random.default_rng(seed).normal(0.0, noise_m, len(v))
    return TriangleSurface(v + offset[:, None] * np.asarray(part.vertex_normals), t[keep])


X_MOVE = np.eye(4)
X_MOVE[:3, :3] = Rotation.from_rotvec([1.2, -0.7, 1.9]).as_matrix()
X_MOVE[:3, 3] = [0.3, -1.0, 0.2]


def _write(vertices, triangles, path):
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    mesh.compute_triangle_normals()
    o3d.io.write_triangle_mesh(str(path), mesh)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("inspect")
    part = _part()
    model = _model(part, noise_m=0.0001)
    v = np.asarray(part.vertices)
    moved_mm = 1e3 * (v @ X_MOVE[:3, :3].T + X_MOVE[:3, 3])
    return {
        "part": part,
        "model": _write(model.vertices, model.triangles, root / "model.ply"),
        "reference_mm": _write(moved_mm, np.asarray(part.triangles), root / "part_mm.stl"),
        "reference_m": _write(v, np.asarray(part.triangles), root / "part.ply"),
        "root": root,
    }


def test_a_moved_reference_in_millimetres_is_found(files):
    part = files["part"]
    model = _model(part, noise_m=0.0001)
    ref = o3d.io.read_triangle_mesh(str(files["reference_mm"]))
    reference = TriangleSurface(np.asarray(ref.vertices), np.asarray(ref.triangles))
    assert reference_unit(model.vertices, reference.vertices) == "mm"
    a = align_reference(model.vertices, reference, unit="mm")
    # The true pose of the reference (as written) in the model's frame is X_MOVE's inverse.
    dt, dr = pose_difference(a.X_MR, np.linalg.inv(X_MOVE))
    assert dt < 0.0005 and np.degrees(dr) < 0.2
    assert a.overlap > 0.95 and a.inlier_rms_m < 0.0003


def test_inspect_reports_the_deviation_and_passes_within_tolerance(files, capsys):
    out = files["root"] / "pass"
    code = main(
        [
            "inspect",
            str(files["model"]),
            "--reference",
            str(files["reference_mm"]),
            "--tolerance",
            "0.0005",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    report = json.loads((out / "inspection.json").read_text())
    assert report["reference_unit"] == "mm" and report["passed"]
    d = report["deviation"]
    # The model's vertices were moved by N(0, 0.1 mm) along their normals.
    assert d["rms_mm"] == pytest.approx(0.1, abs=0.02)
    assert abs(d["mean_mm"]) < 0.02 and d["within_tolerance"] > 0.99
    printed = capsys.readouterr().out
    assert "PASS:" in printed and str(out) in printed
    for name in ("deviation.png", "deviation_mesh.ply", "reference_aligned.ply", "summary.md"):
        assert (out / name).stat().st_size > 0, name
    coloured = o3d.io.read_triangle_mesh(str(out / "deviation_mesh.ply"))
    assert coloured.has_vertex_colors()
    assert "**PASS" in (out / "summary.md").read_text()


def test_out_of_tolerance_fails_with_exit_code_4_and_keeps_the_earlier_inspection(files, capsys):
    model = files["model"]
    args = ["inspect", str(model), "--reference", str(files["reference_m"])]
    assert main([*args, "--tolerance", "0.00005", "--align", "none"]) == 4
    assert "FAIL:" in capsys.readouterr().out
    first = files["root"] / "inspection" / "inspection.json"
    assert not json.loads(first.read_text())["passed"]
    # A second run does not replace the first: it goes to inspection-2.
    assert main([*args, "--align", "none"]) == 0
    assert not json.loads(first.read_text())["passed"]
    assert json.loads((files["root"] / "inspection-2" / "inspection.json").read_text())["passed"]
    # An --out that holds an inspection is refused without --force.
    assert main([*args, "--out", str(files["root"] / "inspection")]) == 2
    assert "--force" in capsys.readouterr().err


def test_a_reference_of_another_part_is_refused_and_nothing_is_written(files, capsys, tmp_path):
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.02, resolution=30)
    other = _write(np.asarray(sphere.vertices), np.asarray(sphere.triangles), tmp_path / "s.ply")
    out = tmp_path / "refused"
    code = main(["inspect", str(files["model"]), "--reference", str(other), "--out", str(out)])
    assert code == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "could not align" in err and "--reference-unit" in err
    assert not out.exists()


def test_bad_inputs_name_what_is_wrong(files, tmp_path, capsys):
    assert main(["inspect", str(tmp_path / "none.ply"), "--reference", "x.ply"]) == 2
    assert "none.ply" in capsys.readouterr().err
    text = tmp_path / "notes.txt"
    text.write_text("not a mesh")
    assert main(["inspect", str(files["model"]), "--reference", str(text)]) == 2
    assert "expected a mesh file" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["inspect", str(files["model"]), "--reference", "x.ply", "--min-within", "1.5"])
    assert e.value.code == 2
    assert "--min-within" in capsys.readouterr().err


def test_a_tolerance_typed_in_millimetres_without_its_unit_is_refused(files, capsys, tmp_path):
    # 0.5 read in metres is 500 mm, more than the ~0.15 m part: it would pass anything.
    args = ["inspect", str(files["model"]), "--reference", str(files["reference_m"])]
    out = tmp_path / "refused"
    assert main([*args, "--tolerance", "0.5", "--out", str(out)]) == 2
    (error,) = capsys.readouterr().err.splitlines()
    assert "--tolerance: 0.5 reads as 0.5 m (500 mm)" in error and "the model's size" in error
    assert "write 0.5mm" in error
    assert not out.exists()
    assert main([*args, "--scale", "2", "--out", str(out)]) == 2
    assert "--scale: 2 reads as 2 m (2000 mm)" in capsys.readouterr().err


@pytest.mark.parametrize("typed", ["0.5mm", "0.0005m", "500um", "0.0005"])
def test_lengths_take_a_unit_and_a_bare_number_is_metres(files, capsys, tmp_path, typed):
    args = ["inspect", str(files["model"]), "--reference", str(files["reference_m"])]
    out = tmp_path / "inspection"
    assert main([*args, "--tolerance", typed, "--align", "none", "--out", str(out)]) == 0
    report = json.loads((out / "inspection.json").read_text())
    assert report["deviation"]["tolerance_mm"] == pytest.approx(0.5, rel=1e-12)


@pytest.mark.parametrize("typed", ["0.5 inch", "mm", "-1mm", "0.0000001", "0.5nm"])
def test_a_bad_length_is_a_usage_error_naming_the_option(files, capsys, typed):
    with pytest.raises(SystemExit) as e:
        main(["inspect", str(files["model"]), "--reference", "x.ply", "--tolerance", typed])
    assert e.value.code == 2
    (error,) = capsys.readouterr().err.splitlines()
    assert "argument --tolerance:" in error
