"""Plot trees from every source, terrains from files, plot files, the stand generator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from treesim.cli import main
from treesim.cloud import Cloud
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.io import write_cloud, write_mesh
from treesim.models import generate_tree, write_cylinders
from treesim.plot import Plot, PlotTree, Terrain
from treesim.plot._sources import fit_species
from treesim.plot.generate import generate_stand, parse_shares
from treesim.plot.io import read_plot, read_trees_csv, write_plot

COFFEE = "pipeline/data/coffee_tree/QSM_treeqsm_v2.4.1_cylinders.csv"


def _box_mesh(path, lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    write_mesh(path, v, f)


def test_mesh_tree_stands_its_stem_base_on_its_position(tmp_path):
    # a 0.4 x 0.2 x 3 m post at (100, 200, 50) in its file: its base's centre moves to
    # the tree's position, on the terrain
    _box_mesh(tmp_path / "post.ply", (99.8, 199.9, 50.0), (100.2, 200.1, 53.0))
    ter = Terrain(z0_m=2.0)
    plot = Plot(
        [PlotTree(tree_id=4, x_m=1.0, y_m=-2.0, source="mesh", path="post.ply")],
        terrain=ter,
        base_dir=str(tmp_path),
    )
    b = plot.tree_bounds(4)
    np.testing.assert_allclose(b, [[0.8, -2.1, 2.0], [1.2, -1.9, 5.0]], atol=1e-9)
    t = plot.truth(4)
    assert t["height_m"] == pytest.approx(3.0) and t["dbh_m"] is None


def test_a_tree_with_a_base_height_stands_there_not_on_the_terrain(tmp_path):
    """``z_m`` puts the stem base at that height (a twin's QSM stands where its field
    cloud put it); without it the tree is seated on the terrain. On a 15° slope the
    post's footprint spans 0.4 m, so the terrain's lowest point under it lies
    0.2 tan(15°) below the terrain at its position: a seated twin tree was lifted."""
    _box_mesh(tmp_path / "post.ply", (99.8, 199.9, 50.0), (100.2, 200.1, 53.0))
    ter = Terrain(kind="slope", z0_m=2.0, slope_deg=15.0, aspect_deg=90.0)
    trees = [
        PlotTree(tree_id=1, x_m=1.0, y_m=-2.0, source="mesh", path="post.ply"),
        PlotTree(tree_id=2, x_m=1.0, y_m=-2.0, z_m=-0.25, source="mesh", path="post.ply"),
    ]
    plot = Plot(trees, terrain=ter, base_dir=str(tmp_path))
    seated, given = plot.tree_bounds(1), plot.tree_bounds(2)
    lowest = min(float(ter.height_at(x, y)) for x in (0.8, 1.2) for y in (-2.1, -1.9))
    assert seated[0, 2] == pytest.approx(lowest, abs=1e-9)
    assert given[0, 2] == pytest.approx(-0.25, abs=1e-12)
    assert given[1, 2] == pytest.approx(2.75, abs=1e-12)
    np.testing.assert_allclose(given[:, :2], seated[:, :2], atol=1e-12)
    with pytest.raises(InvalidParameterError, match="z_m"):
        PlotTree(tree_id=3, x_m=0.0, y_m=0.0, z_m=float("nan"))


def test_qsm_tree_is_meshed_and_its_truth_is_its_table():
    from treesim.models import read_cylinders

    table = read_cylinders(COFFEE)
    plot = Plot([PlotTree(tree_id=1, x_m=5.0, y_m=5.0, source="qsm", path=COFFEE, rotation_deg=90)])
    truth = plot.truth(1)
    s = table.summary()
    assert truth["dbh_m"] == pytest.approx(s["dbh_m"], rel=1e-12)
    assert truth["height_m"] == pytest.approx(s["height_m"], rel=1e-9)
    assert truth["volume_total_m3"] == pytest.approx(s["volume_total_m3"], rel=1e-12)
    # meshed as treesim model from-qsm meshes it: closed tubes, branch starts sunk
    from treesim.models import cylinders_to_mesh, qsm_mesh

    _, faces, sunk = qsm_mesh(table, facets=plot.facets)
    assert sunk is not None and sunk.n_plugs > 0
    n_tri = sum(len(p.faces) for p in plot.tree_parts(1))
    assert n_tri == len(faces)
    assert n_tri > len(cylinders_to_mesh(table, facets=plot.facets, joints="miter")[1])
    b = plot.tree_bounds(1)
    assert b[0, 2] == pytest.approx(0.0, abs=1e-9)  # stands on the flat terrain
    assert b[0, 0] < 5.0 < b[1, 0] and b[0, 1] < 5.0 < b[1, 1]


def test_scaled_tree_truth_scales():
    one = Plot([PlotTree(tree_id=1, x_m=0, y_m=0, source="qsm", path=COFFEE)]).truth(1)
    two = Plot([PlotTree(tree_id=1, x_m=0, y_m=0, source="qsm", path=COFFEE, scale=2.0)]).truth(1)
    assert two["height_m"] == pytest.approx(2 * one["height_m"], rel=1e-9)
    assert two["volume_total_m3"] == pytest.approx(8 * one["volume_total_m3"], rel=1e-9)


def test_cloud_tree_is_reconstructed_once_and_kept(tmp_path, monkeypatch):
    # a vertical stem of radius 10 cm, 2.5 m tall, sampled on its surface
    rng = np.random.default_rng(0)
    n = 6000
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, 2.5, n)
    pts = np.stack([10 + 0.1 * np.cos(a), 20 + 0.1 * np.sin(a), z], 1)
    write_cloud(tmp_path / "stem.laz", Cloud(pts))
    tree = PlotTree(tree_id=1, x_m=0.0, y_m=0.0, source="cloud", path="stem.laz")
    plot = Plot([tree], base_dir=str(tmp_path))
    t = plot.truth(1)
    assert t["dbh_m"] == pytest.approx(0.2, rel=0.1)
    cached = list((tmp_path / ".treesim-cache").glob("*/cylinders.csv"))
    assert len(cached) == 1
    # a second plot reads the kept reconstruction: reconstructing again would fail here
    import importlib

    rec = importlib.import_module("treesim.reconstruct")
    monkeypatch.setattr(rec, "reconstruct", lambda *a, **k: pytest.fail("reconstructed again"))
    again = Plot([tree], base_dir=str(tmp_path)).truth(1)
    assert again["dbh_m"] == t["dbh_m"]


def test_dtm_terrain_is_bilinear_and_fills_nodata(tmp_path):
    # z = 1 + 0.1 x - 0.05 y on cell centres; one NODATA cell
    xs, ys = 0.5 + np.arange(6), 0.5 + np.arange(4)
    z = 1 + 0.1 * xs[None, :] - 0.05 * ys[:, None]  # rows by y
    rows = z[::-1].copy()  # the file's first row is the northernmost
    rows[0, 0] = -9999
    body = "\n".join(" ".join(repr(float(v)) for v in r) for r in rows)
    (tmp_path / "dtm.asc").write_text(
        "ncols 6\nnrows 4\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n" + body
    )
    ter = Terrain(kind="dtm", path="dtm.asc", base_dir=str(tmp_path))
    qx, qy = np.array([1.0, 2.7, 4.2]), np.array([0.9, 1.1, 2.0])
    np.testing.assert_allclose(ter.height_at(qx, qy), 1 + 0.1 * qx - 0.05 * qy, atol=1e-12)
    # beyond the centres: the edge's value
    assert float(ter.height_at(10.0, 1.5)) == pytest.approx(1 + 0.1 * 5.5 - 0.05 * 1.5)
    assert np.isfinite(ter.height_at(0.5, 3.5))  # the NODATA cell took a neighbour's


def test_cloud_terrain_is_linear_inside_and_nearest_outside(tmp_path):
    rng = np.random.default_rng(1)
    xy = rng.uniform(-5, 5, (400, 2))
    pts = np.column_stack([xy, 2.0 + 0.2 * xy[:, 0] + 0.1 * xy[:, 1]])
    write_cloud(tmp_path / "ground.ply", Cloud(pts))
    ter = Terrain(kind="cloud", path=str(tmp_path / "ground.ply"))
    q = np.array([[0.0, 0.0], [1.5, -2.0]])
    np.testing.assert_allclose(
        ter.height_at(q[:, 0], q[:, 1]), 2.0 + 0.2 * q[:, 0] + 0.1 * q[:, 1], atol=1e-12
    )
    far = float(ter.height_at(100.0, 0.0))
    nearest = pts[np.argmin(np.hypot(pts[:, 0] - 100.0, pts[:, 1]))]
    assert far == nearest[2]


@pytest.mark.parametrize(
    "text, match",
    [
        ("ncols 2\nnrows 2\nxllcorner 0\ncellsize 1\n1 2\n3 4\n", "yllcorner"),
        ("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n", "3 cells"),
        ("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 x\n", "not a number"),
    ],
)
def test_bad_dtms_say_what_is_wrong(tmp_path, text, match):
    (tmp_path / "d.asc").write_text(text)
    with pytest.raises(InputFormatError, match=match):
        Terrain(kind="dtm", path=str(tmp_path / "d.asc")).height_at(0.0, 0.0)
    (tmp_path / "d.tif").write_bytes(b"II*\x00")
    with pytest.raises(InputFormatError, match="ESRI ASCII"):
        Terrain(kind="dtm", path=str(tmp_path / "d.tif")).height_at(0.0, 0.0)


def test_species_targets_are_met_and_truth_is_exact():
    tree = PlotTree(tree_id=1, x_m=0, y_m=0, species="aspen", seed=5, dbh_m=0.22, height_m=13.0)
    truth = Plot([tree]).truth(1)
    assert truth["dbh_m"] == pytest.approx(0.22, rel=1e-3)
    assert truth["height_m"] == pytest.approx(13.0, rel=1e-3)
    # the truth is the generated table's own figures
    s = generate_tree(fit_species("aspen", 5, 0.22, 13.0), seed=5).cylinders.summary()
    assert truth["dbh_m"] == s["dbh_m"] and truth["volume_total_m3"] == s["volume_total_m3"]


def test_plot_files_round_trip(tmp_path):
    (tmp_path / "a").mkdir()
    write_cylinders(tmp_path / "a" / "q.csv", generate_tree("sapling", seed=1).cylinders)
    trees = [
        PlotTree(tree_id=3, x_m=1.0 / 3, y_m=-2.5, rotation_deg=12.5, species="aspen", seed=7,
                 dbh_m=0.3, height_m=17.25, leaves=False),
        PlotTree(tree_id=9, x_m=4.0, y_m=0.1, source="qsm", path="q.csv", scale=1.1),
        PlotTree(tree_id=11, x_m=-4.0, y_m=0.2, z_m=0.1 + 0.2, source="qsm", path="q.csv"),
    ]  # fmt: skip
    plot = Plot(
        trees,
        terrain=Terrain(kind="slope", z0_m=0.1, slope_deg=7.0, aspect_deg=200.0),
        radius_m=12.5,
        centre_xy=(0.5, -0.25),
        facets=12,
        terrain_cell_m=0.5,
        base_dir=str(tmp_path / "a"),
    )
    for csv_name in ("trees.csv", None):
        out = tmp_path / f"out-{csv_name}" / "plot.toml"
        out.parent.mkdir()
        write_plot(out, plot, trees_csv=csv_name, stand={"seed": 1, "rule": "x"})
        back = read_plot(out.parent)
        # the paths on their own: the species tree has none, the QSM tree's is written
        # relative to the plot's folder ("q.csv" was relative to "a") and names the same file
        synthetic, qsm, _ = back.trees
        assert synthetic.path is None
        assert qsm.path == "../a/q.csv"
        assert (out.parent / qsm.path).resolve() == (tmp_path / "a" / "q.csv").resolve()
        # every other field as written
        for a, b in zip(back.trees, plot.trees, strict=True):
            assert {k: v for k, v in vars(a).items() if k != "path"} == {
                k: v for k, v in vars(b).items() if k != "path"
            }
        assert back.terrain == plot.terrain
        assert (back.radius_m, back.centre_xy, back.facets, back.terrain_cell_m) == (
            12.5, (0.5, -0.25), 12, 0.5)  # fmt: skip
        assert back.truth(9)["dbh_m"] == plot.truth(9)["dbh_m"]


@pytest.mark.parametrize(
    "csv_text, match",
    [
        ("tree_id,x_m\n1,2\n", "lacks the column"),
        ("tree_id,x_m,y_m\n1,2,x\n", "y_m must be a number"),
        ("tree_id,x_m,y_m,species\n1,2,3,aspen\n1,4,5,aspen\n", "unique"),
        ("tree_id,x_m,y_m,source\n1,2,3,mesh\n", "needs a path"),
        ("tree_id,x_m,y_m,species\n0,2,3,aspen\n", "tree_id"),
        ("tree_id,x_m,y_m\n", "no trees"),
    ],
)
def test_bad_tree_files_say_what_is_wrong(tmp_path, csv_text, match):
    (tmp_path / "trees.csv").write_text(csv_text)
    (tmp_path / "plot.toml").write_text('trees = "trees.csv"\n')
    with pytest.raises(InputFormatError, match=match):
        read_plot(tmp_path)


@pytest.mark.parametrize(
    "toml, match",
    [
        ('trees = "trees.csv"\nradius = 3\n', "unknown key"),
        ("radius_m = 3\n", "no trees"),
        ('trees = "t.csv"\n[terrain]\nkind = "hill"\n', "kind"),
        ('trees = "t.csv"\n[terrain]\nkind = "dtm"\n', "needs a path"),
        ("trees = [", "not a valid TOML"),
    ],
)
def test_bad_plot_files_say_what_is_wrong(tmp_path, toml, match):
    (tmp_path / "plot.toml").write_text(toml)
    with pytest.raises(InputFormatError, match=match):
        read_plot(tmp_path / "plot.toml")


def test_writing_a_plot_into_a_missing_folder_is_a_clear_error(tmp_path):
    from treesim.errors import InvalidParameterError
    from treesim.plot.io import write_plot

    plot = Plot([PlotTree(tree_id=1, x_m=0, y_m=0, species="sapling")])
    with pytest.raises(InvalidParameterError, match="no such folder"):
        write_plot(tmp_path / "gone" / "plot.toml", plot)
    assert not (tmp_path / "gone").exists()


def test_a_missing_tree_file_is_a_clear_error(tmp_path):
    plot = Plot([PlotTree(tree_id=1, x_m=0, y_m=0, source="mesh", path="gone.obj")],
                base_dir=str(tmp_path))  # fmt: skip
    with pytest.raises(InputFormatError, match="gone.obj not found"):
        plot.tree_parts(1)


def test_generator_rules_hold_and_repeat_bit_for_bit():
    plot, stand = generate_stand("aspen:0.6,balsam-fir:0.4", 600, 15.0, seed=1)
    n = round(600 * math.pi * 15.0**2 / 1e4)
    assert len(plot.trees) == stand["trees"] == n
    species = [t.species for t in plot.trees]
    assert species.count("aspen") == round(0.6 * n) and species.count("balsam-fir") == n - round(
        0.6 * n
    )
    xy = np.array([(t.x_m, t.y_m) for t in plot.trees])
    d = np.array([t.dbh_m for t in plot.trees])
    assert (np.hypot(xy[:, 0], xy[:, 1]) <= 15.0).all()
    assert stand["relaxations"] == 0
    s = math.sqrt(1e4 / 600)
    gap = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    need = np.maximum(0.5 * s, 5.0 * (d[:, None] + d[None]))
    np.fill_diagonal(gap, np.inf)
    assert (gap >= need).all()
    assert (d >= 0.05).all()
    h = np.array([t.height_m for t in plot.trees])
    assert (h > 1.3).all()
    again, _ = generate_stand("aspen:0.6,balsam-fir:0.4", 600, 15.0, seed=1)
    assert again.trees == plot.trees
    other, _ = generate_stand("aspen:0.6,balsam-fir:0.4", 600, 15.0, seed=2)
    assert other.trees != plot.trees
    pois, st = generate_stand("aspen", 600, 15.0, seed=1, count="poisson")
    assert len(pois.trees) == st["trees"]


def test_generator_heights_follow_naslund():
    plot, stand = generate_stand("aspen", 800, 15.0, seed=3, height_sd=0.0)
    r = stand["species"]["aspen"]
    for t in plot.trees:
        d = 100 * t.dbh_m
        assert t.height_m == pytest.approx(1.3 + d * d / (r["naslund_a"] + r["naslund_b"] * d) ** 2)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"species": "oak:1"}, "unknown species"),
        ({"species": "aspen:-1"}, "share"),
        ({"stems_per_ha": 0}, "stems_per_ha"),
        ({"count": "grid"}, "count"),
        ({"stems_per_ha": 1e6, "radius_m": 50}, "5000"),
    ],
)
def test_generator_refuses_bad_arguments(kw, match):
    args = {"species": "aspen", "stems_per_ha": 600, "radius_m": 10.0, **kw}
    with pytest.raises(InvalidParameterError, match=match):
        generate_stand(args.pop("species"), args.pop("stems_per_ha"), args.pop("radius_m"), **args)


def test_parse_shares_normalises():
    assert parse_shares("aspen:3,balsam-fir:1") == {"aspen": 0.75, "balsam-fir": 0.25}


def test_cli_generate_then_scan(tmp_path, capsys):
    out = tmp_path / "plot"
    argv = ["plot", "generate", "--species", "sapling", "--stems-per-ha", "300",
            "--radius-m", "4", "--seed", "2", "--facets", "8", "-o", str(out)]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    assert {p.name for p in out.iterdir()} == {"plot.toml", "trees.csv", "map.png"}
    trees = read_trees_csv(out / "trees.csv")
    assert len(trees) == round(300 * math.pi * 16 / 1e4)
    scan_out = tmp_path / "scan"
    argv = ["plot", "scan", str(out), "-o", str(scan_out), "--resolution-deg", "0.5",
            "--stations", "2", "--distance-m", "1.0"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    assert {p.name for p in scan_out.iterdir()} == {
        "plot_scan.laz", "plot_scan.json", "tree_figures.csv"}  # fmt: skip
    import json

    from treesim.io import read_cloud

    info = json.loads((scan_out / "plot_scan.json").read_text())
    cloud = read_cloud(scan_out / "plot_scan.laz")
    assert info["points"] == len(cloud)
    assert sorted(r["tree_id"] for r in info["trees"]) == [t.tree_id for t in trees]
    for r in info["trees"]:
        assert r["points"] == int((cloud.fields["tree_id"] == r["tree_id"]).sum())
    assert set(np.unique(cloud.fields["station"])) == {0, 1}


def test_cli_bad_plot_is_one_line_error(tmp_path, capsys):
    (tmp_path / "plot.toml").write_text('trees = "nope.csv"\n')
    assert main(["plot", "scan", str(tmp_path), "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "nope.csv" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
