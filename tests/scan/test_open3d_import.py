"""A scan imports Open3D without its Plotly/Dash viewer (half of Open3D's import time),
and the viewer still works when called: the real module is imported then."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

CODE = """
import json, sys
from treesim.scan._open3d import load_open3d
o3d = load_open3d()
before = [m for m in ("dash", "plotly") if m in sys.modules]
import numpy as np
scene = o3d.t.geometry.RaycastingScene()
v = np.array([[0, -1, -1], [0, 1, -1], [0, 0, 1]], dtype=np.float32)
scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(np.array([[0, 1, 2]], np.uint32)))
rays = o3d.core.Tensor(np.array([[-2, 0, 0, 1, 0, 0]], dtype=np.float32))
t_hit = float(scene.cast_rays(rays)["t_hit"].numpy()[0])
mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v.astype(float)),
                                 o3d.utility.Vector3iVector(np.array([[0, 1, 2]])))
fig = o3d.visualization.get_plotly_fig([mesh])
after = [m for m in ("dash", "plotly") if m in sys.modules]
print(json.dumps({"before": before, "t_hit": t_hit, "fig": type(fig).__module__ + "." +
                  type(fig).__name__, "after": after}))
"""


def test_open3d_without_its_viewer_casts_and_the_viewer_loads_on_call():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", CODE], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] == []  # not imported for a cast
    assert abs(got["t_hit"] - 2.0) < 1e-6  # the plane x = 0 from x = -2 along +x
    assert got["fig"] == "plotly.graph_objs._figure.Figure"  # the real viewer, on call
    assert got["after"] == ["dash", "plotly"]
