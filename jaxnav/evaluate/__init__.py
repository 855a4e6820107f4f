"""Vectorized evaluation of a policy over fresh episodes, statistics over seeds and their
tables. ``python -m jaxnav.evaluate`` (``__main__.py``) is the command line over it."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.agents.dqn import RecurrentPolicy
from jaxnav.deploy.shield import Shield
from jaxnav.environment import Environment, EnvParams

if TYPE_CHECKING:
    from jaxnav.train import Trainer

# (key, obs[N, D]) -> action[N], or one that keeps a state through each episode (a recurrent
# network's hidden state)
Policy = Callable[[jax.Array, jax.Array], jax.Array] | RecurrentPolicy


def recurrent(policy: Policy) -> RecurrentPolicy:
    """``policy`` as a ``RecurrentPolicy`` (a stateless one keeps None)."""
    if isinstance(policy, RecurrentPolicy):
        return policy
    return RecurrentPolicy(lambda n: None, lambda state, key, obs: (state, policy(key, obs)))


def random_policy(num_actions: int) -> Policy:
    """The paper's random agent: a uniform action every step."""
    return lambda key, obs: jax.random.randint(key, obs.shape[:1], 0, num_actions)


def shielded_policy(network: Any, env: Environment, env_params: Any) -> Callable[[Any], Policy]:
    """params -> the greedy policy of ``network`` on ``env`` among the moves the robot's own
    lidar does not show blocked over the next step (``jaxnav.deploy.shield``); ``ValueError``
    (one line) for a network with memory or an env without lidar."""
    if network.memory:
        raise ValueError("--policy shielded: for feed-forward policies (this one has memory)")
    try:
        shield = Shield.from_layouts(
            env.observation_layout(env_params), env.action_layout(), env.sensor_layout()
        )
    except ValueError as e:
        raise ValueError(f"--policy shielded: {e}") from None
    return lambda p: lambda key, obs: shield.act(network.apply(p, obs), obs, jnp)


def policy_maker(
    policy: str, trainer: Trainer, env: Environment, env_params: Any
) -> Callable[[Any], Policy]:
    """params -> the policy ``policy`` names ("trained": greedy, "shielded":
    ``shielded_policy``, "random") of ``trainer``'s network acting on ``env``."""
    if policy == "random":
        return lambda p: random_policy(env.num_actions)
    if policy == "shielded":
        return shielded_policy(trainer.network, env, env_params)
    return trainer.greedy_policy


def layout_assignment(num_episodes: int, num_layouts: int) -> np.ndarray:
    """The layout of each evaluation episode: round-robin, episode i in layout i mod
    ``num_layouts``, so every layout gets ``num_episodes // num_layouts`` episodes and the first
    ``num_episodes % num_layouts`` one more."""
    return np.arange(num_episodes, dtype=np.int32) % num_layouts


def run_episodes(
    env: Environment,
    params: EnvParams,
    policy: Policy,
    key: jax.Array,
    num_episodes: int,
    max_steps: int,
) -> dict[str, jax.Array]:
    """Play one episode in each of ``num_episodes`` envs for at most ``max_steps`` steps (at
    least the env's time limit); per-episode outcomes.

    The episodes are fixed by ``key`` (the same key gives every agent the same test suite).
    Their layouts (mazes) of the env's bank are assigned round-robin (``layout_assignment``),
    not drawn, so per-layout results rest on a known number of episodes each.
    """
    k_reset, k_run = jax.random.split(key)
    layouts = jnp.asarray(layout_assignment(num_episodes, env.num_layouts(params)))
    obs, state = jax.vmap(env.reset_layout, in_axes=(0, None, 0))(
        jax.random.split(k_reset, num_episodes), params, layouts
    )
    return play(env, params, policy, k_run, obs, state, max_steps)


def play(
    env: Environment,
    params: EnvParams,
    policy: Policy,
    key: jax.Array,
    obs: jax.Array,
    state: Any,
    max_steps: int,
    record: bool = False,
) -> dict[str, jax.Array]:
    """Play the episodes that start at ``(obs, state)`` (a batch, e.g. from ``env.reset_to``
    for a fixed test suite) for ``max_steps`` steps; per-episode outcomes.

    Outcomes: ``return``, ``steps``, ``success``, ``collision``, ``timeout``, ``layout`` (the
    bank layout), ``shortest_path`` (``env.shortest_path_length`` at the start, -1 where not
    known; on the robot envs computed on the host) and ``path_length`` (the sum of
    ``env.step_length`` over the episode).

    Steps without auto-reset (``env.step_no_reset``, the time limit of ``env.step``): an ended
    episode's state stays as it ended, so ``record=True`` also returns ``"states"``, the
    batch's states before the first step and after each one (leading axis ``max_steps + 1``),
    the final pose included. A ``RecurrentPolicy`` starts every episode from its
    ``start`` state (each plays one episode: no state crosses from another).
    """
    num_episodes = obs.shape[0]
    shortest = jax.vmap(env.shortest_path_length, in_axes=(0, None))(state, params)
    layout = jax.vmap(env.layout_index)(state)
    step_length = jax.vmap(env.step_length, in_axes=(0, 0, None))
    zeros = jnp.zeros(num_episodes)
    false = jnp.zeros(num_episodes, bool)
    acting = recurrent(policy)
    init = (obs, state, false, zeros, zeros, zeros, false, false, false, acting.start(num_episodes))
    freeze = lambda ended, old, new: jax.tree.map(  # noqa: E731
        lambda o, n: jnp.where(ended.reshape(ended.shape + (1,) * (n.ndim - 1)), o, n), old, new
    )

    def step(carry, key):
        obs, state, ended, ret, steps, path, success, collision, timeout, memory = carry
        k_pol, k_env = jax.random.split(key)
        memory, action = acting.step(memory, k_pol, obs)
        new_obs, new_state, reward, terminated, truncated, info = jax.vmap(
            env.step_no_reset, in_axes=(0, 0, 0, None)
        )(jax.random.split(k_env, num_episodes), state, action, params)
        live = ~ended
        ret = ret + jnp.where(live, reward, 0.0)
        steps = steps + live
        path = path + jnp.where(live, step_length(state, new_state, params), 0.0)
        success = success | (live & info["goal_reached"])
        collision = collision | (live & info["collision"])
        timeout = timeout | (live & truncated)
        obs, state = freeze(ended, (obs, state), (new_obs, new_state))
        ended = ended | terminated | truncated
        carry = (obs, state, ended, ret, steps, path, success, collision, timeout, memory)
        return carry, (state if record else None)

    carry, states = jax.lax.scan(step, init, jax.random.split(key, max_steps))
    _, _, _, ret, steps, path, success, collision, timeout, _ = carry
    out = {
        "return": ret,
        "steps": steps,
        "success": success,
        "collision": collision,
        "timeout": timeout,
        "shortest_path": shortest,
        "path_length": path,
        "layout": layout,
    }
    if record:
        out["states"] = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), state, states)
    return out


MIN_EPISODES_PER_MAZE = 5  # of every maze played, for a worst-10% success


def maze_success(episodes: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """``(success rate, episodes)`` of each layout (maze) 0 .. max layout played, grouped by
    ``episodes["layout"]`` (a layout without episodes has rate NaN and count 0)."""
    layout = np.asarray(episodes["layout"]).astype(np.int64)
    success = np.asarray(episodes["success"], float)
    counts = np.bincount(layout)
    wins = np.bincount(layout, weights=success, minlength=len(counts))
    with np.errstate(invalid="ignore", divide="ignore"):
        return wins / counts, counts


def worst_fraction_mean(per_maze: np.ndarray, fraction: float = 0.1) -> float:
    """Mean of the lowest ``ceil(fraction * M)`` of ``per_maze``, the success rates of M
    mazes (NaN entries, mazes without episodes, are left out; NaN if none is left).

    With ``fraction=0.1`` this is the worst-10% success: sort the mazes by success rate and
    average the lowest ``ceil(0.1 * M)`` of them, so at least one maze (the worst one for
    M <= 10), 100 of M = 1000. NaN if no maze has episodes.
    """
    x = np.sort(np.asarray(per_maze, float)[~np.isnan(per_maze)])
    if len(x) == 0:
        return float("nan")
    return float(x[: math.ceil(fraction * len(x))].mean())


def spl(success: np.ndarray, shortest: np.ndarray, travelled: np.ndarray) -> float | None:
    """Success weighted by path length (Anderson et al. 2018, as Habitat reports it): the mean
    over episodes of S_i l_i / max(p_i, l_i), S_i success (0 or 1), l_i the shortest path, p_i
    the path travelled; over the episodes whose shortest path is known (l_i > 0), None where
    none is."""
    success, shortest = np.asarray(success, bool), np.asarray(shortest, float)
    travelled = np.asarray(travelled, float)
    known = shortest > 0
    if not known.any():
        return None
    best, p = shortest[known], travelled[known]
    return float(np.mean(np.where(success[known], best / np.maximum(p, best), 0.0)))


def summarize(episodes: dict[str, jax.Array]) -> dict[str, float | None]:
    """Rates over all episodes; steps and path ratio over successful ones.

    ``mean_path_ratio``: path length travelled / shortest path length at the start
    (``env.step_length``, ``env.shortest_path_length``) over successful episodes whose shortest
    path is known; None where there are none (never 0 for something not measured).
    ``spl``: success weighted by path length (``spl``) over the episodes whose shortest path
    is known, None where none is.
    ``worst10_success``: ``worst_fraction_mean`` of the per-maze success rates
    (``maze_success``), None where a single maze was played (it would repeat the success
    rate) or a maze was played fewer than ``MIN_EPISODES_PER_MAZE`` times (with one episode a
    maze's rate is 0 or 1 and the worst 10% is 0 by construction);
    ``mazes``: the mazes played.
    """
    ep = {k: np.asarray(v) for k, v in episodes.items()}
    success = ep["success"].astype(bool)
    n_success = max(int(success.sum()), 1)
    shortest = ep["shortest_path"].astype(float)
    has_path = success & (shortest > 0)
    travelled = ep.get("path_length", ep["steps"]).astype(float)
    per_maze, counts = (
        maze_success(ep) if "layout" in ep else (np.array([success.mean()]), [success.shape[0]])
    )
    played = np.asarray(counts)[np.asarray(counts) > 0]  # episodes of each maze played
    out: dict[str, float | None] = {
        "episodes": float(success.shape[0]),
        "success_rate": float(success.mean()),
        "collision_rate": float(ep["collision"].mean()),
        "timeout_rate": float(ep["timeout"].mean()),
        "mean_return": float(ep["return"].mean()),
        "mean_steps": float(np.where(success, ep["steps"], 0).sum() / n_success),
        "mean_path_ratio": (
            float((travelled[has_path] / shortest[has_path]).mean()) if has_path.any() else None
        ),
        "spl": spl(success, shortest, travelled),
        "mazes": float(len(played)),
        "worst10_success": (
            worst_fraction_mean(per_maze, 0.1)
            if len(played) > 1 and played.min() >= MIN_EPISODES_PER_MAZE
            else None
        ),
    }
    return out


def evaluate(
    env: Environment, params: EnvParams, policy: Policy, key: jax.Array, num_episodes: int
) -> dict[str, float]:
    """Summary metrics of ``policy`` on ``num_episodes`` fresh episodes."""
    run = jax.jit(run_episodes, static_argnums=(0, 2, 4, 5))
    max_steps = int(params.max_steps_in_episode)
    return summarize(run(env, params, policy, key, num_episodes, max_steps))


def evaluate_seeds(
    trainer: Trainer,
    params: Any,
    episodes: int,
    seed: int,
    policy: str = "trained",
    per_maze: bool = False,
) -> list[dict[str, Any]]:
    """Greedy (``policy`` "trained"), shielded (``shielded_policy``) or random evaluation of
    each seed's parameters on the same fresh episodes (layouts round-robin, ``run_episodes``);
    ``per_maze`` adds each seed's per-maze success rates (``maze_success``) as the list
    ``"maze_success"``."""
    env, env_params = trainer.env, trainer.env_params
    key = jax.random.key(seed)
    max_steps = int(env_params.max_steps_in_episode)

    policy_of = policy_maker(policy, trainer, env, env_params)

    def one(p):
        return run_episodes(env, env_params, policy_of(p), key, episodes, max_steps)

    out = jax.device_get(jax.jit(jax.vmap(one))(params))
    n = jax.tree.leaves(params)[0].shape[0]
    rows: list[dict[str, Any]] = []
    for i in range(n):
        one_seed = jax.tree.map(lambda x, i=i: x[i], out)
        row: dict[str, Any] = dict(summarize(one_seed))
        if per_maze:
            row["maze_success"] = [
                None if np.isnan(v) else float(v) for v in maze_success(one_seed)[0]
            ]
        rows.append(row)
    return rows


def mean_of(rows: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """Per metric, the mean over ``rows`` (seeds) of the values that are numbers (None where
    no row has one); lists (per-maze values) are left out."""
    out: dict[str, float | None] = {}
    for k in rows[0]:
        if isinstance(rows[0][k], (list, tuple, dict)):
            continue
        vals = [r[k] for r in rows if r.get(k) is not None]
        out[k] = float(np.mean(vals)) if vals else None
    return out


# ------------------------------------------------------------------ statistics over seeds
def iqm(values: Sequence[float]) -> float:
    """Interquartile mean: the mean of the middle half, ``floor(n / 4)`` values cut from each
    end of the sorted values (``scipy.stats.trim_mean(x, 0.25)``; the mean for n < 4)."""
    from scipy import stats  # only where statistics over seeds are drawn: slow to import

    return float(stats.trim_mean(np.asarray(values, float), 0.25))


def bootstrap_ci(
    values: Sequence[float],
    statistic: Callable[[np.ndarray], float] = np.mean,
    num_resamples: int = 2000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float] | None:
    """Percentile bootstrap interval of ``statistic`` over ``values`` (one per seed):
    ``num_resamples`` resamples of the seeds with replacement (a fixed ``seed``, so the same
    values give the same interval); None for fewer than 2 values."""
    x = np.asarray(values, float)
    if len(x) < 2:
        return None
    idx = np.random.default_rng(seed).integers(0, len(x), (num_resamples, len(x)))
    stats = np.array([statistic(x[i]) for i in idx])
    tail = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(stats, [tail, 100 - tail])
    return float(lo), float(hi)


def t_interval(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over axis 0 (seeds) and the half-width of its 95% t-interval (0 for one seed)."""
    from scipy import stats  # only where an interval is drawn: it is slow to import

    n = x.shape[0]
    mean = x.mean(axis=0)
    if n < 2:
        return mean, np.zeros_like(mean)
    return mean, stats.t.ppf(0.975, n - 1) * x.std(axis=0, ddof=1) / np.sqrt(n)


def seed_statistics(values: Sequence[float | None]) -> dict[str, Any]:
    """Over seeds: ``seeds`` (values that are numbers), ``mean``, ``iqm`` and their 95%
    bootstrap intervals ``mean_ci95`` / ``iqm_ci95`` (``[lo, hi]``, None for one seed); None
    statistics where no seed has a value."""
    x = [float(v) for v in values if v is not None and not np.isnan(v)]
    if not x:
        return {"seeds": 0, "mean": None, "mean_ci95": None, "iqm": None, "iqm_ci95": None}
    mean_ci, iqm_ci = bootstrap_ci(x), bootstrap_ci(x, iqm)
    return {
        "seeds": len(x),
        "mean": float(np.mean(x)),
        "mean_ci95": None if mean_ci is None else list(mean_ci),
        "iqm": iqm(x),
        "iqm_ci95": None if iqm_ci is None else list(iqm_ci),
    }


# ------------------------------------------------------------------------------- tables
SEED_STATISTICS = ("success_rate", "worst10_success")  # with IQM and intervals over seeds
EVAL_COLUMNS = (
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "worst10_success",
    "mean_return",
    "mean_steps",
    "mean_path_ratio",
    "spl",
)


def format_value(value: float | None, digits: int = 3) -> str:
    """A table cell: ``n/a`` for a value not measured (None or NaN)."""
    if value is None or value != value:
        return "n/a"
    return f"{value:.{digits}f}"


def print_eval_table(env: str, rows: dict[str, dict[str, float | None]]) -> None:
    """Means over seeds per policy; ``worst10_success`` is the mean success of the 10% of
    mazes with the lowest success (``worst_fraction_mean``)."""
    first = next(iter(rows.values()))
    mazes = first.get("mazes")
    per = f" over {mazes:.0f} mazes" if mazes is not None and mazes > 1 else ""
    print(f"\n{env}: {first['episodes']:.0f} episodes per policy{per}")
    print("| policy | " + " | ".join(EVAL_COLUMNS) + " |")
    print("|---" * (len(EVAL_COLUMNS) + 1) + "|")
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(format_value(r.get(c)) for c in EVAL_COLUMNS) + " |")


def format_interval(stat: dict[str, Any], key: str) -> str:
    """``0.912 [0.880, 0.940]`` from ``seed_statistics``'s ``key`` and ``key_ci95``."""
    ci = stat[f"{key}_ci95"]
    tail = "" if ci is None else f" [{ci[0]:.3f}, {ci[1]:.3f}]"
    return format_value(stat[key]) + tail


def print_seed_statistics(stats: dict[str, dict[str, Any]]) -> None:
    """Per metric over seeds: mean and IQM with 95% bootstrap intervals, and the seed count;
    nothing for a metric no seed measured (``worst10_success`` of one maze)."""
    for metric, st in stats.items():
        if not st["seeds"]:
            continue
        print(
            f"{metric} over {st['seeds']} seeds: mean {format_interval(st, 'mean')}, "
            f"IQM {format_interval(st, 'iqm')} (95% bootstrap intervals)"
        )
