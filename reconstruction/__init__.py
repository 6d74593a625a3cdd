# Before any module of this package imports Open3D: its import without the notebook viewer
# (reconstruction/common/open3d_loading.py says why).
from reconstruction.common.open3d_loading import defer_open3d_viewer

defer_open3d_viewer()
