"""``--physics KEY=VALUE`` on every simulating command: checked by PhysicsSettings before any meshing."""

import json

import pytest

import latticeopt.coupled
import latticeopt.mesh
from latticeopt.cli import main

COARSE = ["--sensor-size", "50", "--size", "5", "--no-cache"]


@pytest.mark.parametrize("command", [
    ["indent", "--touch", "25,25,7.5,1", *COARSE],
    ["simulate", "--touch", "25,25,7.5,1", *COARSE],
    ["sweep", "studies/quick.toml", "--dry-run"],
    ["optimize", "studies/optimize_square.toml", "--dry-run"],
    ["sensitivity", "studies/sensitivity_press.toml", "--vary", "rim=channel"],
    ["calibrate", "studies/data/paper_press_measured.csv", "--fit", "hydrogel_shear_kPa=1:50"],
])
@pytest.mark.parametrize("item, fragments", [
    ("hydrogel_poisson_ratio=0.5", ["--physics hydrogel_poisson_ratio", "< 0.5", "got 0.5"]),
    ("silicone_poisson_ratio=high", ["--physics silicone_poisson_ratio", "0 <= silicone_poisson_ratio", "'high'"]),
    ("poisson_ratio=0.49", ["--physics poisson_ratio", "hydrogel_poisson_ratio", "got 'poisson_ratio'"]),
    ("indenter=cone", ["--physics indenter", "'flat', 'sphere'", "'cone'"]),
    ("edge_radius_mm=-1", ["--physics edge_radius_mm", "0 <= edge_radius_mm <= 20", "got -1"]),
    ("conductivity_law=bogus", ["--physics conductivity_law", "'geometry', 'linear', 'power'", "'bogus'"]),
    ("0.4999", ["--physics", "KEY=VALUE", "'0.4999'"]),
])
def test_bad_physics_is_one_line_exit_2_before_meshing(capsys, monkeypatch, command, item, fragments):
    def no_meshing(*a, **k):  # the check must come first
        raise AssertionError("meshed before checking --physics")

    for module in (latticeopt.mesh, latticeopt.coupled):
        monkeypatch.setattr(module, "mesh_design", no_meshing)
    code = main([*command, "--physics", item])
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    for f in fragments:
        assert f in err, (f, err)


def test_simulate_takes_physics_keys(capsys):
    args = ["simulate", "--touch", "25,25,7.5,1", "--json", *COARSE]
    assert main(args) == 0
    soft = json.loads(capsys.readouterr().out)
    assert main([*args, "--physics", "hydrogel_shear_kPa=2.5", "--physics", "hydrogel_poisson_ratio=0.4999",
                 "--physics", "indenter=sphere"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["physics"]["hydrogel_poisson_ratio"] == 0.4999 and out["physics"]["hydrogel_shear_kPa"] == 2.5
    assert out["physics"]["indenter"] == "sphere" and soft["physics"]["indenter"] == "flat"
    assert out["v_rel"] != soft["v_rel"]


def test_indent_takes_physics_keys(capsys):
    args = ["indent", "--touch", "25,25,7.5,1", "--json", *COARSE]
    assert main(args) == 0
    base = json.loads(capsys.readouterr().out)
    # a stiffer silicone needs more force for the same depth
    assert main([*args, "--physics", "silicone_shear_kPa=46"]) == 0
    stiff = json.loads(capsys.readouterr().out)
    assert stiff["forces_N"][0] > 1.5 * base["forces_N"][0]


def test_sweep_physics_goes_into_the_study_table_as_values(capsys, tmp_path):
    from latticeopt.cli._physics import physics_values
    from latticeopt.study.config import load_study

    class Args:
        physics = ["hydrogel_poisson_ratio=0.4999", "indenter=sphere"]

    values = physics_values(Args())
    assert values == {"hydrogel_poisson_ratio": 0.4999, "indenter": "sphere"}
    study = load_study("studies/quick.toml", physics=values)
    assert study.settings.physics == {"hydrogel_poisson_ratio": 0.4999, "indenter": "sphere"}
    assert study.settings.physics_settings.indenter == "sphere"
    assert main(["sweep", "studies/quick.toml", "--dry-run", "--physics", "hydrogel_poisson_ratio=0.4999",
                 "--out", str(tmp_path)]) == 0


def test_physics_is_checked_once_by_the_study_and_named_by_its_flag(monkeypatch, capsys):
    """The one check of a study's [physics] is PhysicsSettings.from_dict inside EvalSettings: the CLI hands the
    parsed values over unchecked, and the loader names a bad one after the flag that gave it."""
    from latticeopt.coupled import PhysicsSettings

    calls = []
    real = PhysicsSettings.from_dict.__func__

    def counting(cls, values, **kw):
        calls.append(dict(values or {}))
        return real(cls, values, **kw)

    monkeypatch.setattr(PhysicsSettings, "from_dict", classmethod(counting))
    assert main(["sweep", "studies/quick.toml", "--dry-run", "--physics", "hydrogel_poisson_ratio=0.45"]) == 0
    assert [c for c in calls if c.get("hydrogel_poisson_ratio") == 0.45] == [{"hydrogel_poisson_ratio": 0.45}]
    capsys.readouterr()
    for command in (["sweep", "studies/quick.toml", "--dry-run"], ["sensitivity", "studies/sensitivity_press.toml",
                                                                   "--vary", "hydrogel_shear_kPa=2,15", "--dry-run"],
                    ["optimize", "studies/optimize_square.toml", "--dry-run"],
                    ["optimize", "studies/optimize_freeform.toml", "--dry-run"]):
        assert main([*command, "--physics", "hydrogel_poisson_ratio=0.5"]) == 2
        err = capsys.readouterr().err
        assert "--physics hydrogel_poisson_ratio" in err and "got 0.5" in err, (command, err)
        assert "Traceback" not in err and "--set" not in err


def test_a_bad_dedicated_option_is_named_by_its_own_flag(capsys):
    assert main(["simulate", "--touch", "25,25,7.5,1", "--sigma", "-1", "--mesh-size", "8"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--sigma" in err and "--physics" not in err


def test_sensitivity_physics_sets_every_runs_baseline(monkeypatch, capsys):
    import latticeopt.study.sensitivity as sens
    from latticeopt.errors import ParameterError

    seen = {}
    real = sens.load_variants

    def record(path, variations, overrides, physics):
        seen["runs"] = real(path, variations, overrides, physics)
        raise ParameterError("stop", "the test to stop before running", "here")

    monkeypatch.setattr(sens, "load_variants", record)
    code = main(["sensitivity", "studies/sensitivity_press.toml", "--vary", "hydrogel_shear_kPa=2,15",
                 "--physics", "hydrogel_poisson_ratio=0.4999"])
    assert code == 2 and "stop" in capsys.readouterr().err
    runs = seen["runs"]
    assert len(runs) == 3  # the baseline and one per value
    assert all(study.settings.physics["hydrogel_poisson_ratio"] == 0.4999 for *_, study in runs)
    assert [study.settings.physics.get("hydrogel_shear_kPa") for *_, study in runs][1:] == [2, 15]
