"""Study files: the shipped studies load; bad files are rejected with the file and key named; --set."""

from __future__ import annotations

import dataclasses
import inspect
import re
from pathlib import Path

import pytest

from latticeopt.design import DESIGN_FIELDS, LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.mesh import MeshSettings
from latticeopt.study.config import PHYSICS_KEYS, EvalSettings, load_study, parse_override

STUDIES = Path(__file__).parents[1] / "studies"

BASE = """
name = "t"
out = "runs/t"
[design]
thickness_mm = 3.0
[grid]
width_mm = [0, 4]
[phantoms]
seed = 1
counts = { 1 = 2, 2 = 1 }
[mesh]
size_mm = 5.0
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


def test_paper_fig4_is_the_papers_grid():
    s = load_study(STUDIES / "paper_fig4.toml")
    assert s.kind == "grid" and s.grid_fields == ("thickness_mm", "width_mm")
    assert {(d.thickness_mm, d.width_mm) for d in s.designs} == {
        (t, w) for t in (1, 2, 3, 4, 5) for w in (0, 2, 3, 4, 5, 6)}
    assert len(s.designs) == 30 and len(s.phantoms) == 300
    assert [sum(p.n_touches == k for p in s.phantoms) for k in (1, 2, 3)] == [100, 100, 100]
    assert s.n_tasks == 9000


def test_quick_is_a_subgrid_of_paper_and_shares_its_phantoms():
    quick, paper = load_study(STUDIES / "quick.toml"), load_study(STUDIES / "paper_fig4.toml")
    assert set(quick.designs) < set(paper.designs) and len(quick.designs) == 12
    assert quick.settings.mesh == type(quick.settings.mesh)()  # the converged default mesh
    first = {(p.n_touches, p.index): p for p in paper.phantoms}
    assert all(first[(p.n_touches, p.index)] == p for p in quick.phantoms)


def test_paper_press():
    s = load_study(STUDIES / "paper_press.toml")
    assert s.kind == "press" and [(d.rim, d.width_mm) for d in s.designs] == [
        (rim, w) for rim in ("none", "channel") for w in (0, 4, 6)]  # both rim layouts
    assert {d.thickness_mm for d in s.designs} == {3.0}
    assert {(t.radius_mm, t.x_mm, t.y_mm) for p in s.phantoms for t in p.touches} == {(8.75, 50.0, 50.0)}
    depths = [p.touches[0].depth_mm for p in s.phantoms]
    assert depths[0] == 0.0 and depths[-1] == 4.0 and depths == sorted(depths)
    assert [c.reference for c in s.phantom_set.compare] == [1.85, 1.13] * 2  # the paper's ratios, per rim layout


def test_tasks_are_design_major(tmp_path):
    s = load_study(_write(tmp_path, BASE))
    tasks = s.tasks()
    assert [d.width_mm for d, _ in tasks] == [0, 0, 0, 4, 4, 4]
    assert [p for _, p in tasks[:3]] == list(s.phantoms) == [p for _, p in tasks[3:]]


@pytest.mark.parametrize("edit, key, fragment", [
    (('name = "t"', 'name = "t"\ncolour = 1'), "colour", "name, description, kind"),  # unknown top-level key
    (("[grid]", "[grid]\nwidht_mm = [1]"), "grid.widht_mm", "width_mm, thickness_mm"),  # typo in a design field
    (("size_mm = 5.0", "size = 5.0"), "mesh.size", "mesher, size_mm"),
    (("[mesh]", "[physics]\nsigma = 1\n[mesh]"), "physics.sigma", ", ".join(PHYSICS_KEYS)),
    (("seed = 1", "seed = 1\ncount = 3"), "phantoms.count", "seed, counts"),
])
def test_unknown_key_named_with_valid_keys(tmp_path, edit, key, fragment):
    path = _write(tmp_path, BASE.replace(*edit))
    with pytest.raises(ParameterError) as info:
        load_study(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {key}:") and fragment in msg


@pytest.mark.parametrize("edit, key", [
    (("width_mm = [0, 4]", "width_mm = [0, 12.5]"), "grid.width_mm"),             # w >= p
    (("thickness_mm = 3.0", "thickness_mm = 3.0\npitch_mm = 3.0"), "grid.width_mm"),  # w = 4 >= p = 3
    (("width_mm = [0, 4]", "width_mm = []"), "grid.width_mm"),                    # empty grid
    (("width_mm = [0, 4]", ""), "grid"),                                          # [grid] with no field
    (("width_mm = [0, 4]", "width_mm = [4, 4.0]"), "grid.width_mm"),              # the same design twice
    (("width_mm = [0, 4]", "width_mm = 4"), "grid.width_mm"),                     # not a list
    (("width_mm = [0, 4]", 'width_mm = ["wide"]'), "grid.width_mm"),              # bad type
    (("thickness_mm = 3.0", "thickness_mm = 8.0"), "design.thickness_mm"),       # no room for the substrate
    (("size_mm = 5.0", 'size_mm = "fine"'), "mesh.size_mm"),
    (("[mesh]", "[physics]\nsigma_S_per_m = -1\n[mesh]"), "physics.sigma_S_per_m"),
    (("[mesh]", '[physics]\npoisson_ratio = "high"\n[mesh]'), "physics.poisson_ratio"),
    (('name = "t"', 'name = "t"\njobs = "two"'), "jobs"),
    (('name = "t"', 'name = "t"\nkind = "random"'), "kind"),
    (('name = "t"', 'name = "t"\nmodel = "nocolon"'), "model"),
    (("counts = { 1 = 2, 2 = 1 }", "counts = { 1 = 0 }"), "phantoms.counts"),
    (("counts = { 1 = 2, 2 = 1 }", "counts = { 7 = 1 }"), "phantoms.counts.7"),
    (("counts = { 1 = 2, 2 = 1 }", "counts = { 1 = 2.5 }"), "phantoms.counts.1"),
    (("seed = 1", "seed = 1\nradius_mm = [8, 6]"), "phantoms.radius_mm"),
    (("seed = 1", "seed = 1\ndepth_mm = [9.2, 9.5]"), "phantoms.depth_mm"),     # deeper than the stack (by range)
    (("[phantoms]", "[press]\nx_mm = 50\n[phantoms]"), "press"),                # press table in a grid study
    (("counts = { 1 = 2, 2 = 1 }", 'only = ["1:3", "1:3"]'), "phantoms.only"),    # listed twice
    (("counts = { 1 = 2, 2 = 1 }", 'only = ["6:0"]'), "phantoms.only"),           # more touches than allowed
    (("counts = { 1 = 2, 2 = 1 }", 'only = "1:3"'), "phantoms.only"),             # not a list
    (("counts = { 1 = 2, 2 = 1 }", 'only = ["1/3"]'), "phantoms.only"),
    (("counts = { 1 = 2, 2 = 1 }", 'only = []'), "phantoms.only"),
    (("seed = 1", 'seed = 1\nonly = ["1:3"]'), "phantoms.only"),                 # not among the counts' 1:0, 1:1
    (("counts = { 1 = 2, 2 = 1 }", 'only = ["1:3"]\ntarget_se = 0.01'), "phantoms.target_se"),
])
def test_invalid_study_rejected_naming_file_and_key(tmp_path, edit, key):
    assert edit[0] in BASE
    path = _write(tmp_path, BASE.replace(*edit, 1))
    with pytest.raises(ParameterError) as info:
        load_study(path)
    assert str(info.value).startswith(f"{path}: {key}:"), str(info.value)


def test_only_picks_phantoms_of_the_study(tmp_path):
    """``phantoms.only`` re-runs some phantoms of a study: the same touches as the whole study's (its streams
    are per phantom), in the order listed, with their indices; from the file or by --set on the study."""
    path = _write(tmp_path, BASE.replace("counts = { 1 = 2, 2 = 1 }", "counts = { 1 = 8, 2 = 5 }"))
    by_key = {(p.n_touches, p.index): p for p in load_study(path).phantoms}
    for picked in (load_study(path, ['phantoms.only=["2:4", "1:7"]']),
                   load_study(_write(tmp_path, path.read_text().replace("2 = 5 }", '2 = 5 }\nonly = ["2:4", "1:7"]')))):
        assert [(p.n_touches, p.index) for p in picked.phantoms] == [(2, 4), (1, 7)]
        assert [p.touches for p in picked.phantoms] == [by_key[2, 4].touches, by_key[1, 7].touches]
    with pytest.raises(ParameterError, match=r"phantoms.only: .*\{ 1 = 8, 2 = 5 \}.*got \['2:5'\]"):
        load_study(path, ['phantoms.only=["2:5"]'])  # the counts draw 2:0 to 2:4
    for bad, shown in (('"2:4"', "'2:4'"), ("nan", "nan"), ('["2:4", "2:4"]', "listed twice")):
        with pytest.raises(ParameterError, match=rf"phantoms.only: .*counts = \{{ 1 = 8, 2 = 5 \}}.*{shown}"):
            load_study(path, [f"phantoms.only={bad}"])  # every bad form names the counts it must come from
    with pytest.raises(ParameterError, match="phantoms.only"):
        load_study(_write(tmp_path, ML.replace("counts = { 1 = 2, 2 = 2 }", 'only = ["1:0", "1:1", "2:0", "2:1"]')))


def test_bad_toml_and_missing_file(tmp_path):
    with pytest.raises(ParameterError, match="valid TOML"):
        load_study(_write(tmp_path, "name = "))
    with pytest.raises(ParameterError, match="readable TOML"):
        load_study(tmp_path / "nope.toml")


def test_press_selector_must_match_one_design(tmp_path):
    text = (BASE.replace("[phantoms]\nseed = 1\ncounts = { 1 = 2, 2 = 1 }", "")
            .replace('name = "t"', 'name = "t"\nkind = "press"')
            + "[press]\ndepths_mm = [1, 2]\n[[press.compare]]\nnumerator = { width_mm = 4 }\n"
              "denominator = { width_mm = 6 }\n")
    with pytest.raises(ParameterError, match=r"press.compare\[0\].denominator: .*matched 0"):
        load_study(_write(tmp_path, text))
    ok = load_study(_write(tmp_path, text.replace("width_mm = 6 }", "width_mm = 0 }")))
    assert [p.touches[0].depth_mm for p in ok.phantoms] == [1.0, 2.0]


def test_set_overrides(tmp_path):
    path = _write(tmp_path, BASE)
    s = load_study(path, ["mesh.size_mm=3", "grid.width_mm=[0, 2, 6]", "phantoms.counts.3=1", "out=elsewhere/x",
                          "physics.indenter=flat", "design.pitch_mm=10"])
    assert s.settings.mesh.size_mm == 3.0 and [d.width_mm for d in s.designs] == [0, 2, 6]
    assert {d.pitch_mm for d in s.designs} == {10.0}
    assert [p.n_touches for p in s.phantoms] == [1, 1, 2, 3]
    assert s.out_dir == Path("elsewhere/x") and s.settings.physics == {"indenter": "flat"}
    with pytest.raises(ParameterError) as info:
        load_study(path, ["grid.width_mm=[0, 20]"])
    assert str(info.value).startswith("--set grid.width_mm:")
    with pytest.raises(ParameterError, match="--set mesh.sise_mm: .*size_mm"):
        load_study(path, ["mesh.sise_mm=3"])
    with pytest.raises(ParameterError, match="--set"):
        load_study(path, ["noequals"])
    with pytest.raises(ParameterError, match="not a table"):
        load_study(path, ["name.x=1"])


def test_parse_override_values():
    assert parse_override("a.b=3") == ("a.b", 3)
    assert parse_override("x=[0,4]") == ("x", [0, 4])
    assert parse_override("x = true") == ("x", True)
    assert parse_override('x="a b"') == ("x", "a b")
    assert parse_override("out=runs/a") == ("out", "runs/a")


def test_settings_key_tracks_what_changes_results():
    base = EvalSettings()
    assert base.key == EvalSettings().key
    assert EvalSettings(mesh=MeshSettings(size_mm=3)).key != base.key
    assert EvalSettings(physics_items=(("sigma_S_per_m", 2.0),)).key != base.key
    assert EvalSettings(model="m:f").key != base.key
    assert EvalSettings(cache_dir="/tmp/x").key == base.key
    a = EvalSettings(physics_items=(("sigma_S_per_m", 2.0), ("indenter", "flat")))
    b = EvalSettings(physics_items=(("indenter", "flat"), ("sigma_S_per_m", 2)))
    assert a.key == b.key and a.physics == {"indenter": "flat", "sigma_S_per_m": 2.0}
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.model = "x:y"


def _set_default(monkeypatch, cls, name: str, value) -> None:
    """Change the default of dataclass field ``name`` for this test (as an edit of the class would)."""
    init = cls.__init__
    names = [p.name for p in inspect.signature(init).parameters.values() if p.default is not p.empty]
    defaults = list(init.__defaults__)
    defaults[names.index(name)] = value
    monkeypatch.setattr(init, "__defaults__", tuple(defaults))


@pytest.mark.parametrize("field_name, value", [("step_rtol", 1e-2), ("method", "newton"), ("max_step_mm", 0.5),
                                               ("precision", "double")])
def test_settings_key_changes_with_a_solver_default(monkeypatch, field_name, value):
    from latticeopt.mechanics import IndentSettings

    before = EvalSettings(physics_items=(("sigma_S_per_m", 2.0),)).key
    _set_default(monkeypatch, IndentSettings, field_name, value)
    assert getattr(IndentSettings(), field_name) == value
    after = EvalSettings(physics_items=(("sigma_S_per_m", 2.0),))
    assert after.key != before
    assert after.as_dict()["physics"]["indent"][field_name] == value


def test_settings_key_changes_with_a_mesh_default_and_the_package_version(monkeypatch):
    import latticeopt

    base = EvalSettings()
    key = base.key
    assert set(base.as_dict()["mesh"]) == {f.name for f in dataclasses.fields(MeshSettings)}
    assert base.as_dict()["version"] == latticeopt.__version__
    monkeypatch.setattr(latticeopt, "__version__", latticeopt.__version__ + ".post1")
    assert EvalSettings().key != key
    monkeypatch.undo()
    assert EvalSettings().key == key
    _set_default(monkeypatch, MeshSettings, "channel_cells", 3)
    assert EvalSettings().key != key


def test_settings_the_default_model_rejects_are_named_by_their_physics_key():
    with pytest.raises(ParameterError, match=r"^physics\.mechanics_rtol: .*0\.1"):
        EvalSettings(physics_items=(("mechanics_rtol", 0.5),)).key  # noqa: B018 - the key resolves the settings


def test_settings_key_of_a_custom_model_uses_its_table_as_given(monkeypatch):
    from latticeopt.mechanics import IndentSettings

    custom = EvalSettings(model="m:f", physics_items=(("indenter", "flat"),))
    assert custom.as_dict()["physics"] == {"indenter": "flat"}  # another model's defaults are its own
    key = custom.key
    _set_default(monkeypatch, IndentSettings, "step_rtol", 1e-2)
    assert EvalSettings(model="m:f", physics_items=(("indenter", "flat"),)).key == key


def test_grid_may_vary_any_design_field(tmp_path):
    text = BASE.replace("width_mm = [0, 4]", "pitch_mm = [10, 12.5]\nelectrode_width_mm = [3, 4]")
    s = load_study(_write(tmp_path, text))
    assert len(s.designs) == 4 and all(isinstance(d, LatticeDesign) for d in s.designs)
    assert set(s.grid_fields) <= set(DESIGN_FIELDS)


def test_package_version_is_the_distribution_version():
    """The version is part of every store and mesh key: the one in pyproject.toml and the package agree."""
    import tomllib
    from pathlib import Path

    import latticeopt

    meta = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert latticeopt.__version__ == meta["project"]["version"]


ML = BASE.replace("counts = { 1 = 2, 2 = 1 }", "counts = { 1 = 2, 2 = 2 }") + """
[multilevel]
coarse = { size_mm = 8.0, channel_cells = 1 }
pilot = 4
"""


def test_multilevel_table_loads_and_its_absence_is_the_plain_estimator(tmp_path):
    s = load_study(_write(tmp_path, ML))
    assert s.multilevel.coarse == MeshSettings(size_mm=8.0, channel_cells=1)
    assert (s.multilevel.pilot, s.multilevel.se_factor, s.multilevel.control) == (4, 1.1, "fixed")
    assert load_study(_write(tmp_path, ML), ["multilevel.control=fitted"]).multilevel.control == "fitted"
    assert s.settings.mesh == MeshSettings(size_mm=5.0)  # [mesh] stays the fine level
    assert load_study(_write(tmp_path, ML), ["multilevel.pilot=7"]).multilevel.pilot == 7
    assert load_study(_write(tmp_path, BASE)).multilevel is None


@pytest.mark.parametrize("edit, key", [
    ("pilot = 4.5", "multilevel.pilot"),
    ("pilot = 1", "multilevel.pilot"),
    ("pilot = 4\nse_factor = 0.9", "multilevel.se_factor"),
    ("pilot = 4\nse_factor = true", "multilevel.se_factor"),
    ("pilot = 4\nsteps = 3", "multilevel.steps"),
    ('pilot = 4\ncontrol = "beta"', "multilevel.control"),
    ("pilot = 4\ncontrol = 1", "multilevel.control"),
])
def test_multilevel_errors_name_the_key(tmp_path, edit, key):
    with pytest.raises(ParameterError) as info:
        load_study(_write(tmp_path, ML.replace("pilot = 4", edit)))
    assert info.value.name == f"{tmp_path / 's.toml'}: {key}"


@pytest.mark.parametrize("coarse, key", [("{ size_mm = -1 }", "multilevel.coarse.size_mm"),
                                         ("{ size = 4 }", "multilevel.coarse.size"),
                                         ("{ size_mm = 5.0 }", "multilevel.coarse"),
                                         ("4.0", "multilevel.coarse")])
def test_multilevel_coarse_mesh_errors_name_the_key(tmp_path, coarse, key):
    with pytest.raises(ParameterError) as info:
        load_study(_write(tmp_path, ML.replace("{ size_mm = 8.0, channel_cells = 1 }", coarse)))
    assert info.value.name.endswith(f": {key}")


def test_multilevel_needs_two_phantoms_per_touch_count_and_a_grid_study(tmp_path):
    with pytest.raises(ParameterError, match="phantoms.counts"):
        load_study(_write(tmp_path, ML.replace("counts = { 1 = 2, 2 = 2 }", "counts = { 1 = 2, 2 = 1 }")))
    with pytest.raises(ParameterError) as info:
        load_study(tmp_path / "s.toml", ["multilevel.pilot=0"])
    assert info.value.name == "--set multilevel.pilot"


def test_multilevel_count_error_quotes_the_numbers_and_a_setting_that_raises_them(tmp_path):
    path = _write(tmp_path, ML.replace("counts = { 1 = 2, 2 = 2 }", "counts = { 1 = 3, 2 = 1, 3 = 0 }"))
    with pytest.raises(ParameterError) as info:
        load_study(path)
    assert info.value.got == {1: 3, 2: 1}  # phantoms per touch count, not the list of touch counts
    hint = re.search(r"--set '([^']+)'", str(info.value))
    assert hint and hint.group(1) == "phantoms.counts={ 1 = 3, 2 = 2 }"
    assert load_study(path, [hint.group(1)]).multilevel.pilot == 4  # the suggested setting is accepted


def test_quick_study_takes_the_two_level_estimator_once_its_counts_are_raised():
    with pytest.raises(ParameterError, match=r"got \{1: 1, 2: 1, 3: 1\}"):
        load_study(STUDIES / "quick.toml", ["multilevel.pilot=15"])
    study = load_study(STUDIES / "quick.toml", ["multilevel.pilot=15", "phantoms.counts={ 1 = 2, 2 = 2, 3 = 2 }"])
    assert study.multilevel.pilot == 15 and len(study.phantoms) == 6
