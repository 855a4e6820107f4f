"""Training presets: the ``TrainConfig`` values tuned for each (algorithm, env id), in one place.

Fields a preset leaves out keep ``TrainConfig``'s defaults, which are the paper's grid
experiment with the DQN. ``TrainConfig.for_env(env, algo=...)`` applies the preset, then the
caller's overrides; the training CLI does the same with its flags. Without an ``algo`` an env
id trains with its default algorithm (``default_algo``): the DQN, except where a PQN preset
measured better (GridMaze-Random-v0).
"""

from __future__ import annotations

from typing import Any

from jaxnav.registration import env_family, registered_envs

# DQN on the robot envs, chosen by measurement (benchmarks/results/robot_sweeps.md): 3-step
# returns and gamma 0.95 (1-step returns with the grid's gamma 0.9 plateau near 0.86 success on
# RobotSimple-v0), and a longer run, since paths take ~40 control steps rather than ~10 cells.
# 64 envs with batch 512 keep the replay ratio of 16 envs with batch 128 (8 sampled transitions
# per env step) in a quarter of the iterations, and scored higher on a GPU and a CPU
# (docs/performance.md).
ROBOT_DQN: dict[str, Any] = {
    "num_envs": 64,
    "batch_size": 512,
    "total_timesteps": 2_000_000,
    "gamma": 0.95,
    "n_step": 3,
    "eps_decay_steps": 400_000,
    # 1250 iterations of 64 envs: 2M steps are 25 whole intervals (the CLI trains exactly the
    # steps asked for; 100_000 was 99,968 steps an interval and ran 2,099,328 steps)
    "log_interval": 80_000,
}

# PQN: LayerNorm network, lambda-returns over rollouts of many envs (Gallici et al. 2024)
PQN: dict[str, Any] = {
    "algo": "pqn",
    "layer_norm": True,
    "num_envs": 64,
    "rollout_length": 8,
    "num_epochs": 2,
    "num_minibatches": 4,
    "td_lambda": 0.65,
    "lr": 1e-3,
    "lr_end": 1e-4,
    # 32 iterations of 64 x 8 steps an interval, 15 intervals: whole intervals, as the CLI asks
    "log_interval": 16_384,
    "total_timesteps": 245_760,
}
ROBOT_PQN: dict[str, Any] = {
    **PQN,
    "num_envs": 256,
    "rollout_length": 16,
    "num_minibatches": 8,
    # 1000 iterations of 256 x 16 steps in 20 intervals of 50 (4M was not a whole number of
    # iterations; it ran 21 intervals of 196,608: 4,128,768 steps)
    "total_timesteps": 4_096_000,
    "gamma": 0.95,
    "eps_decay_steps": 800_000,
    "log_interval": 204_800,
}

# PQN at a GPU's scale for RobotNav-v0, the generalist (docs/evaluation.md: "The generalist robot").
# 8192 envs x 32 steps; 16 minibatches of 16,384 x 4 epochs: 64 gradient steps per 262,144
# transitions. Why these sizes, the wider network and the fused LayerNorm: docs/performance.md
# ("Why the training code is shaped as it is") and benchmarks/results/generalist_sweep_h100.md.
GENERALIST_PQN: dict[str, Any] = {
    **PQN,
    "hidden_sizes": (1024, 512, 256),
    "compute_dtype": "bfloat16",
    "fused_layer_norm": True,
    "num_envs": 8192,
    "rollout_length": 32,
    "num_minibatches": 16,
    "num_epochs": 4,
    "lr": 2e-3,
    # 3,200 iterations of 8192 x 32 steps in 80 intervals of 40: whole intervals
    "total_timesteps": 838_860_800,
    "gamma": 0.99,
    "td_lambda": 0.9,
    "eps_decay_steps": 20_000_000,
    "log_interval": 10_485_760,
}

# PQN for GridMaze-Random-v0 (random layouts, the sensor observation with a waypoint 3 cells
# ahead), its default algorithm, chosen by measurement on this 2-core CPU
# (benchmarks/grid_random_sweep.py, table in benchmarks/results/grid_random_sweep.md): the DQN's
# greedy policies kept 2-4% of held-out episodes oscillating between two cells (240k or 400k
# steps, gamma 0.95 or a step penalty alike), while PQN steps the env several times faster and
# passed 0.98. A 256-128-64 MLP trains about 3x faster per env step than the paper's
# 512-256-128-64 here and, given twice the steps, scored the same.
GRID_RANDOM_PQN: dict[str, Any] = {
    **PQN,
    "hidden_sizes": (256, 128, 64),
    "total_timesteps": 1_920_000,
    "log_interval": 128_000,  # 250 iterations of 512 env steps: 1.92M is 15 of them
}

# PPO (PureJaxRL's recipe): a policy whose logits are the network's outputs (no dueling
# heads: they would add a state's value to every logit) and a value network of the same
# widths, GAE(0.95) over rollouts, 4 epochs of 4 minibatches. No epsilon: actions are sampled.
PPO: dict[str, Any] = {
    "algo": "ppo",
    "dueling": False,
    "num_envs": 16,
    "rollout_length": 32,
    "num_epochs": 4,
    "num_minibatches": 4,
    "td_lambda": 0.95,
    "lr": 1e-3,
    "lr_end": 1e-4,
    "max_grad_norm": 0.5,
    "eps_start": 0.0,
    "eps_end": 0.0,
    # 32 iterations of 16 x 32 steps an interval, 15 intervals: whole intervals
    "log_interval": 16_384,
    "total_timesteps": 245_760,
}
# ROBOT_PQN's envs, rollout and minibatches; on RobotSimple-v0 a quarter of the run (1,024,000
# steps) reached 0.938 greedy success on 500 episodes (random agent 0.034)
ROBOT_PPO: dict[str, Any] = {
    **PPO,
    "num_envs": 256,
    "rollout_length": 16,
    "num_minibatches": 8,
    # 1000 iterations of 256 x 16 steps in 20 intervals of 50, as ROBOT_PQN
    "total_timesteps": 4_096_000,
    "gamma": 0.95,
    "log_interval": 204_800,
}
# PPO at GENERALIST_PQN's scale, for comparing the two on the same levels: its envs, rollout,
# minibatches, epochs, network and run length; PPO's own learning rate, lambda and clipping.
_GENERALIST_SHARED = (
    "hidden_sizes", "compute_dtype", "num_envs", "rollout_length", "num_minibatches",
    "num_epochs", "total_timesteps", "gamma", "log_interval",
)  # fmt: skip
GENERALIST_PPO: dict[str, Any] = {
    **PPO,
    **{k: GENERALIST_PQN[k] for k in _GENERALIST_SHARED},
    "lr": 3e-4,
    "lr_end": 3e-5,
}

# algo -> env family (its env class's ``family``) -> the preset of ids without their own
FAMILY_PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    "dqn": {"grid": {}, "robot": ROBOT_DQN},
    "pqn": {"grid": PQN, "robot": ROBOT_PQN},
    "ppo": {"grid": PPO, "robot": ROBOT_PPO},
}
# algo -> env id -> its own preset
ID_PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    "pqn": {
        "GridMaze-Random-v0": GRID_RANDOM_PQN,
        "RobotNav-v0": GENERALIST_PQN,
        "RobotJaxNav-v0": GENERALIST_PQN,  # the generalist's sensors, on JaxNav's levels
        "RobotNavMapfree-v0": GENERALIST_PQN,
    },
    "ppo": {
        "RobotNav-v0": GENERALIST_PPO,
        "RobotJaxNav-v0": GENERALIST_PPO,
        "RobotNavMapfree-v0": GENERALIST_PPO,
    },
}
# algo -> env id -> preset, for every registered id
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    algo: {
        env_id: ID_PRESETS.get(algo, {}).get(env_id, by_family.get(env_family(env_id), {}))
        for env_id in registered_envs()
    }
    for algo, by_family in FAMILY_PRESETS.items()
}


# env id -> the algorithm it trains with when none is given (others: "dqn")
DEFAULT_ALGOS: dict[str, str] = {"GridMaze-Random-v0": "pqn"}


def default_algo(env_id: str) -> str:
    """The algorithm ``env_id`` trains with when none is given."""
    return DEFAULT_ALGOS.get(env_id, "dqn")


def train_defaults(env_id: str, algo: str | None = None) -> dict[str, Any]:
    """``TrainConfig`` values tuned for ``algo`` (default: ``default_algo(env_id)``) on
    ``env_id``; ``ValueError`` naming the valid choices for an unknown id or algorithm."""
    if env_id not in registered_envs():
        raise ValueError(f"unknown env id {env_id!r}; valid ids: {', '.join(registered_envs())}")
    algo = default_algo(env_id) if algo is None else algo
    if algo not in PRESETS:
        raise ValueError(f"algo={algo!r}: must be one of {', '.join(PRESETS)}")
    return dict(PRESETS[algo].get(env_id, {}))
