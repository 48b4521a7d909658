"""One typed path for ``[physics]``: a study's table is checked once into ``PhysicsSettings``, which the key and the
coupled model use as it is; the store's settings key is composed as before, so existing stores stay valid."""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle

import pytest

import latticeopt
import latticeopt.coupled as coupled
from latticeopt.coupled import PhysicsSettings
from latticeopt.errors import ParameterError
from latticeopt.mesh import MeshSettings
from latticeopt.study.settings import DEFAULT_MODEL, EvalSettings, MultilevelSettings, coarse_level_settings

TABLE = {"hydrogel_poisson_ratio": 0.4999, "indenter": "sphere", "sigma_S_per_m": 2}


def _key(obj: dict) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def test_the_settings_key_hashes_the_resolved_physics_as_the_store_expects():
    mesh = MeshSettings(size_mm=3)
    s = EvalSettings(mesh=mesh, physics_items=tuple(TABLE.items()))
    resolved = PhysicsSettings(**TABLE)
    want = {"mesh": mesh.identity(), "model": DEFAULT_MODEL, "version": latticeopt.__version__,
            "physics": {**resolved.as_dict(), "indent": resolved.indent_settings().as_dict()}}
    assert s.key == _key(want)
    custom = EvalSettings(mesh=mesh, physics_items=tuple(TABLE.items()), model="m:f")
    # another model keys on the table as given (values cleaned: 2 -> 2.0), not on PhysicsSettings' defaults
    assert custom.key == _key({**want, "model": "m:f", "physics": {**TABLE, "sigma_S_per_m": 2.0}})
    assert custom.physics == {**TABLE, "sigma_S_per_m": 2.0}


def test_the_table_is_validated_once_and_the_model_gets_that_object(monkeypatch):
    built = []
    check = PhysicsSettings.__post_init__
    monkeypatch.setattr(PhysicsSettings, "__post_init__", lambda self: (built.append(1), check(self)))
    s = EvalSettings(physics_items=tuple(TABLE.items()))
    assert len(built) == 1
    taken = []
    monkeypatch.setattr(coupled, "CoupledModel", lambda design, mesh, physics, *rest: taken.append(physics))
    coupled.model_for_settings(None, s)
    assert s.key and s.as_dict()["physics"]["indenter"] == "sphere"
    assert len(built) == 1 and taken == [s.physics_settings] and taken[0] is s.physics_settings
    again = pickle.loads(pickle.dumps(s))  # as a worker receives it
    assert again.physics_settings == s.physics_settings and again.key == s.key


def test_each_entry_names_a_bad_value_its_own_way():
    with pytest.raises(ParameterError, match=r"^physics\.hydrogel_poisson_ratio: "):
        EvalSettings(physics_items=(("hydrogel_poisson_ratio", 0.5),))
    with pytest.raises(ParameterError, match=r"^physics: expected keys among .*got 'sigma'"):
        EvalSettings(physics_items=(("sigma", 1),))
    with pytest.raises(ParameterError, match=r"^coarse_physics\.mechanics_rtol: "):
        MultilevelSettings(coarse_physics={"mechanics_rtol": 2})
    from latticeopt.cli._physics import physics_settings

    with pytest.raises(ParameterError, match=r"^--physics indenter: "):
        physics_settings(argparse.Namespace(physics=["indenter=cone"]))
    resolved = physics_settings(argparse.Namespace(physics=["sigma_S_per_m=2", "indenter=sphere"]))
    assert (resolved.sigma_S_per_m, resolved.indenter) == (2.0, "sphere")


def test_the_coarse_level_merges_its_keys_into_the_fine_table():
    fine = EvalSettings(physics_items=(("mechanics_rtol", 1e-5), ("indenter", "sphere")))
    coarse = coarse_level_settings(fine, MultilevelSettings())
    assert coarse.physics_settings == PhysicsSettings(mechanics_rtol=1e-2, indenter="sphere")
    assert coarse.physics == {"mechanics_rtol": 1e-2, "indenter": "sphere"}
