"""Loading never executes data: a crafted SB3 zip, a crafted ``.vecnormalize.pkl`` and a crafted
sidecar, loaded every way the docs show, run nothing (docs/trust.md)."""

from __future__ import annotations

import base64
import json
import pickle
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from nutribench.agents.api import TrainedAgent, eval_food_streams, evaluate, train
from nutribench.agents.model_files import ModelFileError, load_plugin_model
from nutribench.cli import app

REPO = Path(__file__).resolve().parents[1]


class Payload:
    """Unpickled, it writes ``marker``: what an attacker plants in a model file."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"import pathlib; pathlib.Path({self.marker!r}).write_text('ran')",))


def plant(model: Path, marker: Path) -> None:
    """Rewrite the SB3 zip ``model`` so that unpickling its ``data`` runs :class:`Payload`,
    and replace the ``.vecnormalize.pkl`` beside it by a payload too."""
    with zipfile.ZipFile(model) as zf:
        members = {i.filename: zf.read(i) for i in zf.infolist()}
    data = json.loads(members["data"])
    data["policy_class"] = {
        ":type:": "<class 'type'>",
        ":serialized:": base64.b64encode(pickle.dumps(Payload(marker))).decode(),
    }
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(model, "w") as zf:
        for name, blob in members.items():
            zf.writestr(name, blob)
    model.with_suffix(".vecnormalize.pkl").write_bytes(pickle.dumps(Payload(marker)))


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> tuple[TrainedAgent, Path]:
    """A PPO agent (observations normalised) trained one day and saved."""
    agent = train("run3", "ppo", seed=2, episodes=1)
    assert agent.vec_normalize is not None  # so a .vecnormalize.pkl is written beside it
    return agent, agent.save(tmp_path_factory.mktemp("m") / "ppo.zip")


@pytest.fixture
def evil(saved, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the saved model with payloads planted; the file they would write."""
    _, path = saved
    out = tmp_path / "evil.zip"
    for suffix in (".zip", ".json", ".vecnormalize.pkl"):
        out.with_suffix(suffix).write_bytes(path.with_suffix(suffix).read_bytes())
    marker = tmp_path / "PWNED"
    plant(out, marker)
    return out, marker


def test_the_planted_payload_is_live(evil):
    """The control: plain SB3 loading the crafted zip (and pickle loading the .pkl) runs it."""
    from stable_baselines3 import PPO

    path, marker = evil
    with pytest.raises(TypeError):  # the payload returned None as the policy class, after it ran
        PPO.load(path, device="cpu")
    assert marker.read_text() == "ran"
    marker.unlink()
    pickle.loads(path.with_suffix(".vecnormalize.pkl").read_bytes())
    assert marker.exists()


def test_trained_agent_load_reads_weights_and_runs_nothing(saved, evil):
    agent, _ = saved
    path, marker = evil
    loaded = TrainedAgent.load(path)
    assert not marker.exists()
    streams = eval_food_streams("run3", 2, 2)
    assert evaluate(loaded, "run3", streams).steps == evaluate(agent, "run3", streams).steps
    assert loaded.vec_normalize_stats is not None and np.allclose(
        loaded.vec_normalize_stats["obs_rms"]["mean"], agent.vec_normalize.obs_rms.mean
    )
    loaded.save(path.parent / "again.zip")  # saving again copies the pickle's bytes, never loads them
    assert not marker.exists()


def test_the_vec_normalize_statistics_are_rebuilt_from_json(saved):
    from nutribench.agents.model_files import vec_normalize_from_stats
    from nutribench.env.sb3 import NutriRLSB3VecEnv

    agent, path = saved
    vn = vec_normalize_from_stats(TrainedAgent.load(path).vec_normalize_stats, NutriRLSB3VecEnv(regime="run3"))
    obs = np.random.default_rng(1).uniform(0, 2, size=(8, len(agent.obs_mean))).astype(np.float32)
    assert not vn.training and np.allclose(vn.normalize_obs(obs), agent.normalize(obs))
    assert (
        np.array_equal(vn.obs_rms.var, agent.vec_normalize.obs_rms.var) and vn.clip_obs == agent.vec_normalize.clip_obs
    )


def test_a_crafted_sidecar_chooses_no_code(evil, tmp_path: Path, monkeypatch):
    """A sidecar naming ``pwnmod`` (found in the current folder) imports nothing."""
    path, marker = evil
    (tmp_path / "pwnmod.py").write_text(
        f"import pathlib\npathlib.Path({str(marker)!r}).write_text('ran')\ndef make_agent(*a):\n    pass\ndef load(path):\n    pass\n"
    )
    monkeypatch.chdir(tmp_path)
    side = json.loads(path.with_suffix(".json").read_text())
    side["load_with"] = "pwnmod:load"  # a built-in's loader named by the sidecar: ignored
    path.with_suffix(".json").write_text(json.dumps(side))
    TrainedAgent.load(path)
    side["algo"] = "external"
    side["config"] = {
        "algo": "external",
        "name": "evil",
        "version": 1,
        "description": "x",
        "entry_point": "pwnmod:make_agent",
    }
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ModelFileError, match="name its loader"):
        TrainedAgent.load(path)
    side["algo"] = "pwnmod:make_agent"
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ModelFileError, match="not a registered algorithm"):
        TrainedAgent.load(path)
    assert not marker.exists() and "pwnmod" not in sys.modules


def test_evaluate_with_the_example_loader_runs_nothing(evil, tmp_path: Path, monkeypatch):
    pytest.importorskip("sb3_contrib", reason="the example's optional extra (pip install -e '.[contrib]')")
    path, marker = evil
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the docs run it from the repository root
    args = ["evaluate", "--model", str(path), "--entry-point", "examples.recurrent_ppo:load", "--name", "evil"]
    db = tmp_path / "lab.db"
    res = CliRunner().invoke(app, [*args, "--regime", "run3", "--db", str(db)])
    assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1, res.output
    path.with_suffix(".json").unlink()  # a bare crafted zip: refused too
    res = CliRunner().invoke(app, [*args, "--regime", "run3", "--db", str(db)])
    assert res.exit_code == 2 and "no evil.json beside it" in res.output, res.output
    assert not marker.exists()


def test_report_trajectory_and_the_recorder_run_nothing(saved, evil, tmp_path: Path, monkeypatch):
    """The recorder evaluates a model loaded the documented way; the report draws its days
    from the database with the crafted files beside it."""
    import nutribench

    path, marker = evil
    monkeypatch.chdir(path.parent)
    db = tmp_path / "lab.db"
    with nutribench.Recorder(db=str(db), name="loaded", regime="run3", seed=0) as rec:
        rows = rec.evaluate(TrainedAgent.load(path).model)
    assert len(rows) == 5
    res = CliRunner().invoke(
        app,
        ["report", "--trajectory", "--algo", "loaded", "--regime", "run3", "--seed", "0", "--db", str(db)]
        + ["--out", str(tmp_path / "out")],
    )
    assert res.exit_code == 0, res.output
    assert not marker.exists()


A2C_PLUGIN = """
from stable_baselines3 import A2C
from nutribench.agents.model_files import load_plugin_model


def make_agent(params, env, seed):
    return A2C("MlpPolicy", env, seed=seed, device="cpu", **params)


def load(path):
    return load_plugin_model(path, make_agent)
"""


def test_a_plugin_model_loads_by_the_loader_the_user_names(tmp_path: Path, monkeypatch):
    from stable_baselines3 import A2C

    from nutribench.agents.config import parse_agent_config

    (tmp_path / "trust_plugin.py").write_text(A2C_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    cfg = parse_agent_config(
        {
            "algo": "external",
            "name": "a2c_t",
            "version": 1,
            "description": "x",
            "entry_point": "trust_plugin:make_agent",
            "params": {"n_steps": 5},
        }
    )
    agent = train("run3", cfg, seed=1, episodes=1)
    path = agent.save(tmp_path / "a2c.zip")
    loaded = TrainedAgent.load(path, load_with="trust_plugin:load")
    obs = np.random.default_rng(0).uniform(0, 1, size=(16, agent.model.observation_space.shape[0])).astype(np.float32)
    assert np.array_equal(loaded.act(obs)[0], agent.act(obs)[0])
    import trust_plugin

    assert np.array_equal(
        load_plugin_model(path, trust_plugin.make_agent).predict(obs, deterministic=True)[0], agent.act(obs)[0]
    )
    with pytest.raises(ModelFileError, match="unpickles"):  # an SB3 class as loader: only when trusted
        TrainedAgent.load(path, load_with=A2C)
    assert TrainedAgent.load(path, load_with=A2C, trust=True).algo == "external"


def test_an_older_sidecar_loads_by_its_regime_or_with_trust(saved, tmp_path: Path):
    """A sidecar without spaces (written before they were recorded): the spaces of the regime
    its provenance names, if that is a regime name here; else only SB3's load, when trusted."""
    agent, original = saved
    path = tmp_path / "old.zip"
    path.write_bytes(original.read_bytes())
    side = json.loads(original.with_suffix(".json").read_text())
    del side["spaces"]
    path.with_suffix(".json").write_text(json.dumps(side))
    obs = np.ones((3, agent.model.observation_space.shape[0]), dtype=np.float32)
    assert np.array_equal(TrainedAgent.load(path).act(obs)[0], agent.act(obs)[0])
    side["provenance"]["regime"] = str(REPO / "regimes" / "run3.toml")  # a path: never looked up
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ModelFileError, match="trust=True"):
        TrainedAgent.load(path)
    assert np.array_equal(TrainedAgent.load(path, trust=True).act(obs)[0], agent.act(obs)[0])


def test_a_committed_model_loads_as_data(tmp_path: Path):
    """A model of reports/sensitivity (saved before the spaces were recorded) loads without trust."""
    import tarfile

    with tarfile.open(REPO / "reports" / "sensitivity" / "data" / "models_control.tar.gz") as tar:
        names = [f"run3-v2/ppo-v1/seed0-ep5000{s}" for s in (".zip", ".json")]
        for name in names:
            member = tar.getmember(name)
            (tmp_path / Path(name).name).write_bytes(tar.extractfile(member).read())
    agent = TrainedAgent.load(tmp_path / "seed0-ep5000.zip")
    assert agent.algo == "ppo" and agent.obs_mean is not None and agent.provenance["episodes"] == 5000
    from stable_baselines3 import PPO

    sb3 = PPO.load(tmp_path / "seed0-ep5000.zip", device="cpu")  # a committed file: SB3's own load, to compare
    obs = np.random.default_rng(0).uniform(0, 2, size=(64, len(agent.obs_mean))).astype(np.float32)
    assert np.array_equal(agent.act(obs)[0], sb3.predict(agent.normalize(obs), deterministic=True)[0])


def test_a_zip_bomb_of_weights_is_refused_before_it_inflates(saved, tmp_path: Path, monkeypatch):
    import nutribench.agents.model_files as mf

    _, original = saved
    path = tmp_path / "big.zip"
    for suffix in (".zip", ".json"):
        path.with_suffix(suffix).write_bytes(original.with_suffix(suffix).read_bytes())
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("zeros.pth", b"\0" * (4 << 20))  # 4 MiB of zeros: a few KiB compressed
    monkeypatch.setattr(mf, "MAX_MODEL_BYTES", 2 << 20)
    with pytest.raises(ModelFileError, match="would inflate"):
        TrainedAgent.load(path)


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda cfg: cfg.update(net_arch=[40000, 40000, 40000]), "net_arch [40000, 40000, 40000]"),
        (lambda cfg: cfg.update(net_arch=[20000, 20000]), "net_arch [20000, 20000]"),
    ],
)
def test_a_sidecar_whose_layers_the_weights_do_not_hold_is_refused_before_building(
    saved, tmp_path: Path, monkeypatch, edit, named
):
    """Issue 52: ``net_arch = [40000, 40000, 40000]`` in a sidecar built a network of 3.2 billion
    parameters before its weights were looked at (``RuntimeError ... tried to allocate 6400000000
    bytes``). The parameters the config implies are weighed against the zip's tensors first."""
    import nutribench.agents.registry as registry

    _, original = saved
    path = tmp_path / "big.zip"
    path.write_bytes(original.read_bytes())
    side = json.loads(original.with_suffix(".json").read_text())
    edit(side["config"])
    path.with_suffix(".json").write_text(json.dumps(side))

    def never(*args, **kwargs):
        raise AssertionError("a model was built")

    monkeypatch.setattr(registry, "make_model", never)
    with pytest.raises(ModelFileError) as refused:
        TrainedAgent.load(path)
    line = str(refused.value)
    assert "\n" not in line and line.startswith(f"{path.with_suffix('.json')}: its config's layers ({named})"), line
    assert "parameters, but the weights of big.zip hold" in line and "not built" in line, line

    side["algo"] = "external"  # a plug-in's SB3 policy_kwargs, through load_plugin_model
    side["config"] = {"algo": "external", "name": "big", "version": 1, "description": "x", "entry_point": "m:make"}
    side["config"]["params"] = {"policy_kwargs": {"net_arch": {"pi": [40000, 40000], "vf": [40000, 40000]}}}
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ModelFileError, match=r"at least 3,200,160,000 parameters, but the weights of big\.zip hold"):
        load_plugin_model(path, never)


def test_a_sidecar_whose_layers_no_machine_holds_is_refused_by_the_config_bounds(saved, tmp_path: Path, monkeypatch):
    """``net_arch = [10**12]`` in a sidecar (more than any machine holds: nutribench.config.sizes)
    is refused as its config is read, in one line naming the sidecar and the field, before any
    weights are weighed or a model built."""
    import nutribench.agents.registry as registry
    from nutribench.config.reading import ConfigError

    _, original = saved
    path = tmp_path / "big.zip"
    path.write_bytes(original.read_bytes())
    side = json.loads(original.with_suffix(".json").read_text())
    side["config"].update(net_arch=[10**12])
    path.with_suffix(".json").write_text(json.dumps(side))

    def never(*args, **kwargs):
        raise AssertionError("a model was built")

    monkeypatch.setattr(registry, "make_model", never)
    with pytest.raises(ConfigError) as refused:
        TrainedAgent.load(path)
    line = str(refused.value)
    assert "\n" not in line and line.startswith(f"{path.with_suffix('.json')}: net_arch: a network of"), line
    assert "TiB of memory" in line, line


def test_the_shipped_agents_layers_are_within_their_weights():
    """The check above never refuses a model its config built: the fewest parameters each
    shipped agent file's layers imply are no more than its built policy holds."""
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.model_files import _regime_spaces, implied_parameters, stand_in_env
    from nutribench.agents.registry import make_model, names

    spaces = _regime_spaces({"provenance": {"regime": "run3"}})
    for algo in names():
        cfg = load_agent_config(algo)
        model = make_model(cfg, stand_in_env(spaces, algo), seed=0, horizon=50)
        named, fewest = implied_parameters(cfg.model_dump(mode="json"))
        held = sum(t.numel() for t in model.policy.state_dict().values())
        assert named and 0 < fewest <= held, (algo, named, fewest, held)
