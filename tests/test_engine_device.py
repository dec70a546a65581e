"""The batched engine's device (``--device auto|cpu|cuda``): ``auto`` is the CPU
where there is no CUDA, CUDA asked for where there is none is one line (exit 2, before the
database is touched), an explicit CPU run is the default run bit for bit, and the device
travels to the workers in the job specs. The tests marked "needs CUDA" run only where torch
sees a GPU: there each algorithm trains a few days on CUDA and hands back CPU agents that
evaluate, a checkpoint made on CUDA resumes on the CPU, and one PPO update on CUDA equals the
CPU's to float32 tolerance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from typer.testing import CliRunner

from nutribench.agents import eval_food_streams, evaluate
from nutribench.agents.config import load_agent_config
from nutribench.cli import app
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.device import DeviceError, check_device, resolve_device
from nutribench.engine.train import train_batched
from nutribench.scheduler.driver import GridSettings, RunError, run_grid
from nutribench.scheduler.synthetic import synthetic_batch
from tests.test_engine_checkpoint import JOBS, Stopped, same_agents

needs_cuda = pytest.mark.skipif(not th.cuda.is_available(), reason="needs CUDA")
ALGOS = ("mc", "ppo", "gru_ppo", "ddqn", "sac")
#: training days per algorithm: enough for a few updates of :func:`tiny`'s configs
DAYS = {"mc": 3, "ppo": 4, "gru_ppo": 4, "ddqn": 3, "sac": 2}


def tiny(algo: str):
    """The shipped config, cut so that a few days hold several updates (and DDQN's target
    copies, SAC's learning from its second day)."""
    update = {
        "ppo": dict(n_steps=100, n_epochs=2, batch_size=50),
        "gru_ppo": dict(n_steps=100, n_epochs=2, batch_size=50),
        "ddqn": dict(learning_starts=60, target_update_interval=40, buffer_size=300),
        "sac": dict(learning_starts=64, batch_size=32),
    }.get(algo, {})
    return load_agent_config(algo).model_copy(update=update)


@pytest.fixture
def no_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    """This process sees no CUDA (as this machine), whatever the machine has."""
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)


# --------------------------------------------------------------------------- choosing the device
def test_auto_is_the_cpu_without_cuda_and_cuda_there_is_refused_in_one_line(no_cuda) -> None:
    assert resolve_device("auto") == th.device("cpu") == resolve_device("cpu") == resolve_device(th.device("cpu"))
    check_device("auto")
    for name in ("cuda", "cuda:0", "CUDA"):
        with pytest.raises(DeviceError) as err:
            resolve_device(name)
        message = str(err.value)
        assert "CUDA is not available" in message and "--device cpu" in message and "\n" not in message
        with pytest.raises(DeviceError):
            check_device(name)
    for name in ("tpu", "cuda:x", "cpu:0", ""):
        with pytest.raises(DeviceError, match="use auto, cpu, cuda or cuda:N"):
            resolve_device(name)


def test_auto_is_cuda_where_there_is_cuda() -> None:
    assert resolve_device("auto").type == ("cuda" if th.cuda.is_available() else "cpu")


def _one_line_exit_2(args: list[str], cli=None) -> str:
    result = CliRunner().invoke(cli or app, args)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1, result.output
    return " ".join(result.output.split())


def test_run_refuses_a_device_it_cannot_train_on_before_touching_the_database(no_cuda, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    common = ["run", "--regimes", "run0", "--algos", "ppo", "--seeds", "0", "--episodes", "2", "--db", str(db)]
    out = _one_line_exit_2(common + ["--engine", "batched", "--device", "cuda"])
    assert "--device cuda: CUDA is not available here" in out and "--device cpu" in out
    assert "use auto, cpu, cuda" in _one_line_exit_2(common + ["--engine", "batched", "--device", "tpu"])
    assert "the SB3 engine trains on the CPU" in _one_line_exit_2(common + ["--engine", "sb3", "--device", "cuda"])
    assert not db.exists() and not (tmp_path / "models").exists()
    with pytest.raises(DeviceError):  # the library's entry refuses too, before the database
        run_grid(GridSettings(db, ["run0"], ["ppo"], [0], 2, 1, engine="batched", device="cuda", display=False))
    with pytest.raises(RunError, match="SB3 engine trains on the CPU"):
        run_grid(GridSettings(db, ["run0"], ["ppo"], [0], 2, 1, device="cuda:0", display=False))
    assert not db.exists()


def test_the_benchmarks_refuse_a_device_they_cannot_train_on_before_training(no_cuda) -> None:
    assert "CUDA is not available" in _one_line_exit_2(["bench", "train", "--engine", "batched", "--device", "cuda"])
    from tests.conftest import benchmark_script

    learn, engines = benchmark_script("learn").app, benchmark_script("engines").app
    assert "SB3 engine trains on the CPU" in _one_line_exit_2(["--device", "cuda"], learn)
    assert "use auto, cpu, cuda" in _one_line_exit_2(["--device", "gpu"], engines)


class DeviceLog:
    """A batch worker that notes the device each spec carries, then runs the synthetic batch."""

    def __init__(self, folder: str):
        self.folder = folder

    def __call__(self, specs, sink=None):
        for spec in specs:
            (Path(self.folder) / f"job{spec.job_id}-{spec.device}").touch()
        return synthetic_batch(specs, sink)


def test_the_device_travels_to_the_workers_in_the_job_specs(tmp_path: Path) -> None:
    log = tmp_path / "log"
    log.mkdir()
    s = run_grid(
        GridSettings(
            tmp_path / "r.db",
            ["run0"],
            ["ppo"],
            [0, 1],
            4,
            1,
            workers=1,
            batch_fn=DeviceLog(str(log)),
            display=False,
            engine="batched",
            device="cpu",
        )
    )
    assert (s.done, s.failed) == (2, 0)
    assert sorted(f.name.split("-")[1] for f in log.iterdir()) == ["cpu", "cpu"]


# --------------------------------------------------------------------------- the CPU unchanged
@pytest.mark.parametrize("algo", ALGOS)
def test_an_explicit_cpu_run_is_the_default_run_bit_for_bit(algo: str) -> None:
    cfg = tiny(algo)
    default = train_batched(JOBS, cfg, DAYS[algo])
    assert len(default[0].train_episodes) == DAYS[algo] and default[0].provenance["device"] == "cpu"
    same_agents(default, train_batched(JOBS, cfg, DAYS[algo], device="cpu"))
    same_agents(default, train_batched(JOBS, cfg, DAYS[algo], device=th.device("cpu")))
    if not th.cuda.is_available():
        same_agents(default, train_batched(JOBS, cfg, DAYS[algo], device="auto"))


def test_a_checkpoint_read_onto_the_device_it_was_read_onto_is_not_read_again(tmp_path: Path) -> None:
    path = tmp_path / "batch.pt"
    Checkpoint(path).save(x=th.ones(2))
    checkpoint = Checkpoint(path, device="cpu")
    state = checkpoint.state
    assert checkpoint.read_onto(th.device("cpu")) is state and state["x"].device.type == "cpu"


# --------------------------------------------------------------------------- CUDA, where there is one
def _on_cpu(agent) -> bool:
    return all(t.device.type == "cpu" for t in agent.model.policy.state_dict().values())


@needs_cuda
@pytest.mark.parametrize("algo", ALGOS)
def test_each_algorithm_trains_on_cuda_and_hands_back_cpu_agents_that_evaluate(algo: str, tmp_path: Path) -> None:
    agents = train_batched(JOBS, tiny(algo), DAYS[algo], device="cuda")
    for (regime, seed), agent in zip(JOBS, agents, strict=True):
        assert (
            _on_cpu(agent) and len(agent.train_episodes) == DAYS[algo] and agent.provenance["device"].startswith("cuda")
        )
        assert all(np.isfinite(d["return"]) for d in agent.train_episodes)
        played = evaluate(agent, regime, eval_food_streams(regime, seed, 2))
        assert len(played.episodes) == 2 and all(np.isfinite(e["return"]) for e in played.episodes)
    agents[0].save(tmp_path / "agent.zip")


@needs_cuda
@pytest.mark.parametrize("algo", ["gru_ppo", "sac"])
def test_a_checkpoint_made_on_cuda_resumes_on_the_cpu(algo: str, tmp_path: Path) -> None:
    days = {"gru_ppo": 6, "sac": 4}[algo]

    def kill(j: int, row: dict) -> None:
        if row["episode"] == days - 2:
            raise Stopped

    path = tmp_path / "batch.pt"
    with pytest.raises(Stopped):
        train_batched(
            JOBS, tiny(algo), days, on_episode=kill, checkpoint=Checkpoint(path, every_seconds=0), device="cuda"
        )
    checkpoint = Checkpoint(path, every_seconds=0, device="cuda")
    assert checkpoint.state is not None
    agents = train_batched(JOBS, tiny(algo), days, checkpoint=checkpoint, device="cpu")
    assert checkpoint.device == th.device("cpu")
    assert all(_on_cpu(a) and len(a.train_episodes) == days for a in agents)


class AllActiveSGD(th.optim.SGD):
    """Plain SGD taking the engine's ``active`` mask, as the stacked optimisers do (here every
    agent trains: no mask, or one that is all true)."""

    def step(self, closure: None = None, active: np.ndarray | None = None) -> None:  # type: ignore[override]
        assert active is None or bool(np.all(active))
        super().step(closure)


@needs_cuda
def test_one_ppo_update_on_cuda_equals_the_cpu_update() -> None:
    """The update (losses, gradients, per-agent clipping, steps) on CUDA and on the CPU, with
    plain SGD steps: Adam divides each gradient by its running scale, so a gradient that is
    ~0 on one device and rounds to the other sign on the other moves its weight by about
    the learning rate either way (seen on an H100 with the agents' Adam: 1 weight in
    thousands off by up to 0.0036 after one update of 10 epochs); SGD keeps every
    difference the size of float rounding, so the comparison is of the update rule."""
    from nutribench.engine.actor_critic import StackedActorCritic
    from nutribench.engine.on_policy import OnPolicySettings, Rollout
    from nutribench.engine.ppo import ppo_update
    from tests.test_engine import _rollout_of, _sb3_ppo_after_one_rollout

    th.set_num_threads(1)
    made = [_sb3_ppo_after_one_rollout(s, r) for s, r in zip([0, 1, 2], ["run0", "run3", "run0"])]
    cfg, models = made[0][0], [m for _, m in made]
    rollout = _rollout_of(models)
    settings = OnPolicySettings.from_config(cfg, 50)
    rng = np.random.default_rng(7)
    perms = np.stack([[rng.permutation(cfg.n_steps) for _ in models] for _ in range(cfg.n_epochs)])
    nets = {}
    for device in ("cpu", "cuda"):
        net = StackedActorCritic(len(models), models[0].observation_space.shape[0], list(cfg.net_arch), device=device)
        for j, m in enumerate(models):
            net.load_sb3(j, m.policy)
        before = [p.detach().cpu().clone() for p in net.params]
        moved = Rollout(**{name: getattr(rollout, name).to(device) for name in rollout.__dataclass_fields__})
        ppo_update(net, AllActiveSGD(net.params, lr=cfg.learning_rate), moved, settings, perms)
        nets[device] = net
        # the update moves every weight tensor far more than the tolerance below (CPU: 1e-3 to 0.015)
        assert min((p.detach().cpu() - b).abs().max().item() for p, b in zip(net.params, before)) > 1e-4
    assert all(p.device.type == "cuda" for p in nets["cuda"].params)
    for a, b in zip(nets["cpu"].params, nets["cuda"].params, strict=True):
        np.testing.assert_allclose(b.detach().cpu().numpy(), a.detach().numpy(), rtol=1e-4, atol=1e-5)


@needs_cuda
def test_stacked_sac_trials_train_on_cuda(tmp_path: Path) -> None:
    """Stacked SAC trials hold their per-agent settings (alpha, learning rates) as CPU arrays;
    on CUDA the logged means of those meet the networks' CUDA tensors at each day's record (a
    stacked SAC study on a GPU once failed every trial there). Two stacked trials train past
    SAC's first updates (day 3) on CUDA and finish."""
    import optuna

    db = tmp_path / "lab.db"
    args = ["tune", "--algo", "sac", "--study", "cu", "--db", str(db), "--regimes", "run3", "--seeds", "101"]
    args += ["--days", "4", "--eval-every", "2", "--val-episodes", "1", "--trials", "2", "--stack", "2"]
    res = CliRunner().invoke(app, [*args, "--pruner", "none", "--device", "cuda"])
    assert res.exit_code == 0, res.output
    trials = optuna.load_study(study_name="cu", storage=f"sqlite:///{db}").trials
    assert [t.state.name for t in trials] == ["COMPLETE", "COMPLETE"]
    assert all(t.user_attrs["device"].startswith("cuda") and t.user_attrs["stacked_with"] for t in trials)
