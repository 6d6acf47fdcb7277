"""The training section's mapping onto RLlib's PPO and SAC (agents/rllib_train.py) without Ray: the
documented subset is carried over, anything else is refused with the list."""

from __future__ import annotations

from typing import Any

import pytest

from agents.rllib_train import SUPPORTED, training_kwargs
from agents.settings import TrainingSettings
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment


def settings(**training: Any) -> TrainingSettings:
    experiment = load_experiment(example_experiment("cartpole_balance"))
    return TrainingSettings.from_experiment(experiment, training)


def test_the_documented_subset_maps_onto_ppo() -> None:
    hyper = {
        "n_steps": 32,
        "batch_size": 64,
        "n_epochs": 3,
        "learning_rate": "lin_0.001",
        "gamma": 0.98,
        "gae_lambda": 0.8,
        "clip_range": 0.2,
        "ent_coef": 0.01,
        "vf_coef": 0.5,
        "max_grad_norm": 0.7,
        "policy_kwargs": {"net_arch": [16, 8]},
    }
    assert sorted(hyper) == sorted(SUPPORTED["PPO"])
    kwargs, model = training_kwargs(settings(n_envs=4, timesteps=1000, hyperparams=hyper), runners=2)
    assert kwargs == {
        "train_batch_size_per_learner": 32 * 4 * 2,
        "minibatch_size": 64,
        "num_epochs": 3,
        "lr": [[0, 0.001], [1000, 0.0]],
        "clip_param": 0.2,
        "gamma": 0.98,
        "lambda_": 0.8,
        "entropy_coeff": 0.01,
        "vf_loss_coeff": 0.5,
        "grad_clip": 0.7,
    }
    assert model == {"fcnet_hiddens": [16, 8]}


def test_the_documented_subset_maps_onto_sac() -> None:
    hyper = {
        "learning_rate": 0.0007,
        "buffer_size": 50_000,
        "learning_starts": 500,
        "batch_size": 128,
        "gamma": 0.97,
        "tau": 0.01,
        "ent_coef": "auto_0.2",
        "target_entropy": -2,
        "policy_kwargs": {"net_arch": [64, 64]},
    }
    assert sorted(hyper) == sorted(SUPPORTED["SAC"])
    kwargs, model = training_kwargs(settings(algo="SAC", hyperparams=hyper), runners=3)
    assert kwargs == {
        "actor_lr": 0.0007,
        "critic_lr": 0.0007,
        "alpha_lr": 0.0007,
        "replay_buffer_config": {"capacity": 50_000},
        "num_steps_sampled_before_learning_starts": 500,
        "train_batch_size_per_learner": 128,
        "initial_alpha": 0.2,
        "target_entropy": -2.0,
        "gamma": 0.97,
        "tau": 0.01,
    }
    assert model == {"fcnet_hiddens": [64, 64]}
    decay = settings(algo="SAC", timesteps=800, hyperparams={"learning_rate": "lin_0.01"})
    schedule = [[0, 0.01], [800, 0.0]]
    assert training_kwargs(decay, 1)[0] == {"actor_lr": schedule, "critic_lr": schedule, "alpha_lr": schedule}


def test_the_example_sections_own_schedules_map_onto_ppo(caplog: pytest.LogCaptureFixture) -> None:
    """examples/cartpole_balance.yaml as it is: lin_X learning rate a schedule, lin_X clip range
    (RLlib's PPO has no clip schedule) its start value, said in the log."""
    kwargs, _ = training_kwargs(settings(), runners=1)  # lr: lin_0.001, clip_range: lin_0.2
    assert kwargs["lr"] == [[0, 0.001], [150_000, 0.0]]
    assert kwargs["clip_param"] == 0.2
    assert kwargs["train_batch_size_per_learner"] == 32 * 8
    assert "RLlib's PPO has no clip schedule" in caplog.text
    decay = training_kwargs(settings(hyperparams={"ent_coef": "lin_0.01"}, timesteps=400), runners=1)[0]
    assert decay["entropy_coeff"] == [[0, 0.01], [400, 0.0]]


def test_sample_timeout_is_a_setting_and_unset_by_default() -> None:
    assert settings().sample_timeout_s is None  # RLlib's own 60 s would drop a slow plant's samples
    assert settings(sample_timeout_s=900.0).sample_timeout_s == 900.0
    with pytest.raises(ConfigError, match="sample_timeout_s"):
        settings(sample_timeout_s=-1.0)


@pytest.mark.parametrize(
    ("training", "message"),
    [
        ({"algo": "TD3"}, "runs PPO or SAC; the experiment asks for TD3"),
        ({"hyperparams": {"use_sde": True}}, r"\['use_sde'\] have no RLlib PPO mapping"),
        ({"algo": "SAC", "hyperparams": {"train_freq": 4}}, r"\['train_freq'\] have no RLlib SAC mapping"),
        ({"algo": "SAC", "hyperparams": {"ent_coef": 0.1}}, "always learns its entropy coefficient"),
        ({"algo": "SAC", "normalize": True}, "training.normalize"),
        ({"hyperparams": {"policy_kwargs": {"activation_fn": "relu"}}}, "net_arch: \\[sizes\\] only"),
    ],
)
def test_what_has_no_mapping_is_refused(training: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        training_kwargs(settings(**training), runners=1)
