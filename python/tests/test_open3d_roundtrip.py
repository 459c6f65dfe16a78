"""Our PLY/PCD files read by Open3D, and Open3D's files read by sope (issue 15)."""
import numpy as np
import pytest

import sope

o3d = pytest.importorskip("open3d")


def random_cloud(n=2000, seed=5):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, size=(n, 3)).astype(np.float32)
    colors = rng.integers(0, 256, size=(n, 3), dtype=np.uint8)
    return points, colors


@pytest.mark.parametrize("name,ascii_ply", [("ours.ply", False), ("ours_ascii.ply", True),
                                            ("ours.pcd", False)])
def test_open3d_reads_our_files(tmp_path, name, ascii_ply):
    points, colors = random_cloud()
    path = str(tmp_path / name)
    sope.save_cloud(path, points, colors, ascii=ascii_ply)
    cloud = o3d.io.read_point_cloud(path)
    assert len(cloud.points) == len(points)
    np.testing.assert_allclose(np.asarray(cloud.points), points, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(cloud.colors) * 255.0, colors, atol=0.51)


@pytest.mark.parametrize("name,write_ascii", [("o3d.ply", False), ("o3d_ascii.ply", True),
                                              ("o3d.pcd", False), ("o3d_ascii.pcd", True)])
def test_sope_reads_open3d_files(tmp_path, name, write_ascii):
    points, colors = random_cloud(seed=9)
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(points.astype(np.float64))
    cloud.colors = o3d.utility.Vector3dVector(colors.astype(np.float64) / 255.0)
    cloud.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    path = str(tmp_path / name)
    assert o3d.io.write_point_cloud(path, cloud, write_ascii=write_ascii)
    ours = sope.load_cloud(path)
    assert ours["points"].shape == points.shape
    # Open3D writes doubles in PLY; ASCII files carry ~7-17 significant digits.
    np.testing.assert_allclose(ours["points"], points, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(ours["colors"], colors)
    assert ours["normals"] is not None
    np.testing.assert_allclose(ours["normals"][:, 2], 1.0, atol=1e-6)
