"""The batched engine's on-policy diagnostics mean what SB3's logger records: one update of
three stacked agents on the rollouts SB3 collected, and each agent's SB3 ``train()`` on its
own rollout, with the same minibatch orders; every quantity of the batched update's row
(losses, entropy, approximate KL, clip fraction, explained variance, gradient norm,
learning rate) equals the value ``model.logger.name_to_value`` holds after that agent's
update; the gradient norm of SB3's own PPO and A2C (MC), which do not log it, is what the SB3
engine's diagnostics read of it (:class:`~nutribench.agents.training_log.GradNormProbe` on
the model). The return scale is not the update's (it is read off the env's statistics)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from nutribench import diagnostics as names
from nutribench.agents.training_log import DiagnosticsLogger, GradNormProbe
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.gru_ppo import BatchedGRUPPO
from nutribench.engine.mc import BatchedMC
from nutribench.engine.ppo import BatchedPPO
from tests.test_engine import _rollout_of, _sb3_ppo_after_one_rollout

REGIMES = ["run0", "run3", "run0"]
CLASSES = {"ppo": BatchedPPO, "mc": BatchedMC, "gru_ppo": BatchedGRUPPO}
#: the SB3 logger key of each quantity (SB3's PPO and the SB3 engine's GRU-PPO; A2C, MC's
#: class, logs its policy loss as ``train/policy_loss`` and has no KL or clip fraction)
SB3_KEY = {
    names.POLICY_LOSS: "train/policy_gradient_loss",
    names.VALUE_LOSS: "train/value_loss",
    names.ENTROPY_LOSS: "train/entropy_loss",
    names.APPROX_KL: "train/approx_kl",
    names.CLIP_FRACTION: "train/clip_fraction",
    names.EXPLAINED_VARIANCE: "train/explained_variance",
    names.GRAD_NORM: "train/grad_norm",
    names.LEARNING_RATE: "train/learning_rate",
}
LOGGED = {
    "ppo": SB3_KEY,
    "gru_ppo": SB3_KEY,
    "mc": {
        **{n: k for n, k in SB3_KEY.items() if n not in (names.APPROX_KL, names.CLIP_FRACTION)},
        names.POLICY_LOSS: "train/policy_loss",
    },
}
#: what each algorithm's batched row holds besides the update's quantities
NOT_THE_UPDATE = {names.UPDATE, names.TIMESTEP, names.RETURN_SCALE}
EPOCHS = {"ppo": None, "mc": None, "gru_ppo": 3}  # GRU-PPO: 3 epochs (tests/test_engine.py says why)


def one_update(algo: str) -> tuple[list[dict[str, float]], list]:
    """Each agent's batched diagnostics row and its SB3 model, after one update of each."""
    th.set_num_threads(1)
    made = [_sb3_ppo_after_one_rollout(seed, regime, algo) for seed, regime in enumerate(REGIMES)]
    cfg, models = made[0][0], [m for _, m in made]
    if EPOCHS[algo] is not None:
        cfg = cfg.model_copy(update={"n_epochs": EPOCHS[algo]})
        for m in models:
            m.n_epochs = EPOCHS[algo]
    batched = CLASSES[algo](cfg, AgentEnvs(list(zip(REGIMES, range(3))), cfg.normalize_obs), th.device("cpu"))
    for j, m in enumerate(models):
        batched.net.load_sb3(j, m.policy)
    rollout = _rollout_of(models)  # before train(), which flattens SB3's buffer in place
    units = rollout.actions.shape[1] // (batched.settings.sequence_length or 1)  # transitions, or whole days
    perms = []
    for j, m in enumerate(models):  # SB3 draws one permutation per epoch from numpy's global RNG
        np.random.seed(100 + j)
        perms.append([np.random.permutation(units) for _ in range(batched.settings.n_epochs)])
        np.random.seed(100 + j)
        probed = DiagnosticsLogger({})
        probe = GradNormProbe(list(m.policy.parameters()), m.policy.optimizer, probed)
        m.train()
        m.probed_grad_norm = probed.take().get(names.GRAD_NORM)
        probe.remove()
    batched.permutations = lambda _: np.stack(perms, axis=1)
    batched.train(rollout)
    return [rows[-1] for rows in batched.diagnostics], models


@pytest.mark.parametrize("algo", ["ppo", "mc", "gru_ppo"])
def test_every_on_policy_diagnostic_equals_what_sb3_logs_for_the_same_update(algo: str) -> None:
    rows, models = one_update(algo)
    for row, m in zip(rows, models, strict=True):
        assert set(row) - NOT_THE_UPDATE == set(LOGGED[algo])  # each of them is compared below
        logged = dict(m.logger.name_to_value)
        if algo != "gru_ppo":  # SB3's own train() does not log it: the SB3 engine's probe reads it
            assert "train/grad_norm" not in logged
            logged["train/grad_norm"] = m.probed_grad_norm
        for name, key in LOGGED[algo].items():
            assert row[name] == pytest.approx(logged[key], rel=2e-4, abs=1e-7), (name, row[name], logged[key])
        if algo != "mc":  # the KL is the last epoch's: far from zero, unlike the first epoch's
            assert row[names.APPROX_KL] > 1e-6


def test_gru_ppo_of_the_sb3_engine_logs_the_last_epoch_s_approx_kl() -> None:
    """The SB3 engine's GRU-PPO logs ``train/approx_kl`` as SB3's PPO does: its last epoch's."""
    from nutribench.agents.gru_ppo import GRUPPO

    kls: list[float] = []

    class Spy(GRUPPO):
        def ppo_loss(self, data, clip_range):
            loss, stats = super().ppo_loss(data, clip_range)
            kls.append(stats["approx_kl"])
            return loss, stats

    _, model = _sb3_ppo_after_one_rollout(0, "run0", "gru_ppo")
    model.__class__ = Spy
    model.n_epochs = 2
    model.train()
    per_epoch = len(kls) // 2
    assert model.logger.name_to_value["train/approx_kl"] == pytest.approx(np.mean(kls[per_epoch:]), rel=1e-9)
    assert not np.isclose(np.mean(kls[per_epoch:]), np.mean(kls), rtol=1e-6)
