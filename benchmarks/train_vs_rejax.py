"""Our DQN or PQN against rejax's on the same env, network, batch, replay ratio and step count.

``config.algo`` picks the pair. Both train on our env (rejax through ``jaxnav.wrappers.GymnaxV0``,
the gymnax 0.0.x API it expects; GridMaze with its ``onehot`` observation) with one ``TrainConfig``.
DQN: the same MLP (``hidden_sizes``, ReLU, dueling heads when ``dueling``), double-DQN targets when
``double``, ``num_envs`` envs, ``batch_size``, ``updates_per_iteration`` (``replay_ratio *
num_envs / batch_size``) gradient steps per vectorized env step (rejax's ``num_epochs``),
``buffer_size``, ``learning_starts`` random steps (rejax's ``fill_buffer``), a hard target copy
every ``target_update_period`` env steps, gamma, Adam with the same linear learning-rate decay, and
epsilon from ``eps_start`` to ``eps_end`` over ``eps_decay_steps``. What stays rejax's own: its
squared loss (ours: ``config.loss``), elementwise gradient clipping (ours: global norm), and its
treatment of a time limit as terminal (``done``), as every gymnax-0.0.x trainer does.

PQN (``config.algo == "pqn"``, any of our envs): the same MLP with LayerNorm before each ReLU
(rejax's PQN activation) and dueling heads when ``dueling``, ``num_envs`` envs, rollouts of
``rollout_length`` steps, ``num_epochs`` x ``num_minibatches`` gradient steps per rollout,
lambda-returns with ``td_lambda`` and gamma, Adam with the same linear learning-rate decay, and
the same epsilon schedule, observation and reward normalization off. What stays rejax's own:
float32 matrix products (ours: ``compute_dtype``, so give the config float32 for a like
comparison), its squared loss, elementwise gradient clipping, a time limit treated as terminal,
and bootstrapping from the observation after an auto-reset.

Each side is compiled once (reported apart: ``jit(...).lower(...).compile()``) as one logging
interval of ``log_interval`` env steps (ours: ``Trainer.run(ts, i, 1)``, what the CLI runs;
rejax: ``algo.train(train_state=ts)`` with ``total_timesteps = log_interval`` and its
evaluation callback replaced by nothing) and called once on a state of its own, thrown away
(reported apart too: ``first_call_s``, where the program is loaded onto the device, a cost a
process pays once), then the intervals run in turn from a fresh state (ours, rejax, ours, ...),
so load changes on a shared machine hit both alike. After every interval, outside the timed
region, both are evaluated greedily with the same evaluator (``jaxnav.evaluate``) on the same
``eval_episodes`` fresh episodes. Reported per side: compile s, first call s, train s (the
timed intervals), env steps/s, the greedy success curve, and the train time until greedy
success first reached ``threshold``; the wall-time ratio rejax / ours (speed per env step);
and, at equal success, the train time each side took to first reach the best success rejax
reached in the run, and their ratio rejax / ours (speed to a success both reach). Beside the
wall-time ratio, the same ratio over the intervals after each side's first
(``after_first_ratio``): in results recorded before the first call was made apart, the first
timed interval paid the program's loading; now the two ratios differ only by noise. Beside the
final success, each side's mean success over the last quarter of its evaluations
(``late_success``): one evaluation of a trainer whose success swings from check to check says
little about what a run of it delivers, and a mean over several says more. With
``final_episodes``, each side's final policy is also evaluated on that many other fresh
episodes (``final_eval_success``): a check of 256 episodes has a standard error of about 0.013
near 0.95 success, 2,048 episodes about 0.005, enough to tell the two final policies apart.
Over several seeds, the summary ends with the mean of the final policies' difference and its
standard errors (``final_difference``), then each side's median, interquartile mean
(``jaxnav.evaluate.iqm``) and range (``final_spread``): one collapsed run moves a mean, not a
median.

Rejax's programs are compiled as it ships them (``jax.jit``), ours with
``jaxnav.train.COMPILER_OPTIONS`` (XLA's concurrent command-buffer scheduling, loops and
conditionals as CUDA graph nodes, copy insertion by region analysis: options any JAX program
may pass); with ``peer_options`` rejax's are compiled with them too, which shows how much of
the ratio those options make.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
import time
from collections.abc import Callable, Iterable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
import scipy.stats

from jaxnav.config import TrainConfig
from jaxnav.evaluate import iqm, run_episodes, summarize
from jaxnav.train import Trainer, jit_training
from jaxnav.wrappers import GymnaxV0

Side = dict[str, Any]  # one trainer: its compiled interval, state, network and results
LATE_FRACTION = 0.25  # late_success: the mean over this last fraction of the evaluations
# the checks' episodes, and the final evaluation's: other episodes, so that the final policies
# are not scored on the episodes their run's checks saw
CHECK_EPISODES_SEED = 10_000
FINAL_EPISODES_SEED = 20_000


def first_call_s(call: Callable[[], Any]) -> float:
    """Seconds of ``call()``: a compiled interval's first call, on a state of its own that is
    then thrown away. It loads the program's kernels onto the device and instantiates its CUDA
    graphs, once a process, outside the timed training (the trained state starts fresh)."""
    t0 = time.perf_counter()
    jax.block_until_ready(call())
    return time.perf_counter() - t0


def _our_side(trainer: Trainer, key: jax.Array) -> Side:
    c = trainer.config
    t0 = time.perf_counter()
    init = jit_training(trainer.init).lower(key).compile()
    state = init(key)
    interval = jit_training(lambda ts, log: trainer.run(ts, log, 1), donate_argnums=0)
    interval = interval.lower(state, jnp.int32(0)).compile()
    compile_s = time.perf_counter() - t0
    return {
        "name": f"jaxnav {c.algo.upper()}",
        "compile_s": compile_s,
        "first_call_s": first_call_s(lambda: interval(init(key), jnp.int32(0))),
        "state": state,
        "step": lambda ts, i: interval(ts, jnp.int32(i))[0],
        "q_params": lambda ts: ts.params,
        "apply": trainer.network.apply,
        "intervals": c.num_logs,
    }


def _rejax_side(trainer: Trainer, key: jax.Array, peer_options: bool) -> Side:
    import rejax  # bench extra
    from rejax.networks import DiscreteQNetwork, DuelingQNetwork, EpsilonGreedyPolicy

    c = trainer.config
    qnet = DuelingQNetwork if c.dueling else DiscreteQNetwork
    pqn = c.algo == "pqn"

    def layer_norm_relu(x: jax.Array) -> jax.Array:
        return nn.relu(nn.LayerNorm()(x))

    class OurNetwork:
        """rejax's algorithm with our network: rejax 0.1.3 fixes its hidden layers at (64, 64)."""

        @classmethod
        def create_agent(cls, config: dict, env: Any, env_params: Any) -> dict[str, Any]:
            agent = EpsilonGreedyPolicy(qnet)(
                hidden_layer_sizes=tuple(c.hidden_sizes),
                action_dim=env.action_space(env_params).n,
                activation=layer_norm_relu if pqn else nn.relu,
            )
            return {"agent": agent}

    chunk = c.iterations_per_log * c.steps_per_iteration
    common = {
        "env": GymnaxV0(trainer.env),
        "env_params": trainer.env_params,
        "num_envs": c.num_envs,
        "total_timesteps": chunk,  # one logging interval per call; the state carries on
        "eval_freq": chunk,
        "skip_initial_evaluation": True,
        "gamma": c.gamma,
        "learning_rate": optax.linear_schedule(c.lr, c.lr_end, trainer.total_updates),
        "max_grad_norm": c.max_grad_norm,
        "eps_start": c.eps_start,
        "eps_end": c.eps_end,
        # rejax decays over exploration_fraction * total_timesteps of global steps
        "exploration_fraction": c.eps_decay_steps / chunk,
    }
    if pqn:
        base = rejax.PQN
        own = {
            "num_steps": c.rollout_length,
            "num_epochs": c.num_epochs,
            "num_minibatches": c.num_minibatches,
            "td_lambda": c.td_lambda,
            "normalize_observations": False,
            "normalize_rewards": False,
        }
    else:
        base = rejax.DQN
        own = {
            "ddqn": c.double,
            "fill_buffer": c.learning_start_steps,
            "buffer_size": c.buffer_size,
            "batch_size": c.batch_size,
            "num_epochs": c.updates_per_iteration,
            "target_update_freq": c.target_update_period,
            "polyak": 1.0 - c.tau,  # rejax: target = polyak * target + (1 - polyak) * online
        }
    algo = type(f"Our{base.__name__}", (OurNetwork, base), {}).create(**common, **own)
    algo = algo.replace(eval_callback=lambda algo, ts, rng: jnp.zeros(()))
    jit = jit_training if peer_options else jax.jit
    t0 = time.perf_counter()
    init = jit(algo.init_state).lower(key).compile()
    state = init(key)
    train = jit(lambda ts: algo.train(train_state=ts)[0]).lower(state).compile()
    compile_s = time.perf_counter() - t0
    return {
        "name": f"rejax {c.algo.upper()}",
        "compile_s": compile_s,
        "first_call_s": first_call_s(lambda: train(init(key))),
        "state": state,
        "step": lambda ts, i: train(ts),
        "q_params": lambda ts: ts.q_ts.params,
        "apply": algo.agent.apply,
        "intervals": c.num_logs,
    }


def _greedy_success(
    trainer: Trainer, episodes: int, episode_seed: int = CHECK_EPISODES_SEED
) -> Callable[[Callable, Any], float]:
    """(apply, params) -> greedy success rate on the same ``episodes`` fresh episodes (drawn
    from ``episode_seed``)."""
    env, env_params = trainer.env, trainer.env_params
    key = jax.random.key(episode_seed)
    max_steps = int(env_params.max_steps_in_episode)
    compiled: dict[Callable, Callable] = {}

    def success(apply: Callable, params: Any) -> float:
        if apply not in compiled:

            def run(params: Any) -> dict[str, jax.Array]:
                policy = lambda k, obs: jnp.argmax(apply(params, obs), axis=-1)  # noqa: E731
                return run_episodes(env, env_params, policy, key, episodes, max_steps)

            compiled[apply] = jax.jit(run)
        return summarize(compiled[apply](params))["success_rate"]

    return success


def measure(
    config: TrainConfig,
    eval_episodes: int,
    threshold: float,
    seed: int = 0,
    peer_options: bool = False,
    final_episodes: int = 0,
) -> dict[str, Any]:
    """Train both sides interval by interval, in turn; see the module docstring
    (``peer_options``: rejax compiled with ``COMPILER_OPTIONS`` too; ``final_episodes``: the
    size of the final policies' evaluation, 0 for none)."""
    trainer = Trainer(config)
    if trainer.env.obs_onehot_sizes is not None:
        # rejax's network reads observations as numbers: both sides get the one-hot encoding
        # (ours would expand GridMaze's default ``index`` codes to it in the network)
        config = dataclasses.replace(config, env_kwargs={**config.env_kwargs, "obs_mode": "onehot"})
        trainer = Trainer(config)
    key = jax.random.key(seed)
    sides = [_our_side(trainer, key), _rejax_side(trainer, key, peer_options)]
    success = _greedy_success(trainer, eval_episodes)
    chunk = config.iterations_per_log * config.steps_per_iteration
    for side in sides:
        side |= {"train_s": 0.0, "curve": []}
    for i in range(config.num_logs):
        for side in sides:
            t0 = time.perf_counter()
            side["state"] = jax.block_until_ready(side["step"](side["state"], i))
            side["train_s"] += time.perf_counter() - t0
            rate = success(side["apply"], side["q_params"](side["state"]))
            side["curve"].append(
                {"env_steps": (i + 1) * chunk, "train_s": side["train_s"], "success": rate}
            )
            print(
                f"{side['name']:10s} {(i + 1) * chunk:9,} env steps: train "
                f"{side['train_s']:7.1f} s, greedy success {rate:.3f}",
                file=sys.stderr,
            )
    out = {}
    for side in sides:
        reached = first_reaching(side["curve"], threshold)
        out[side["name"]] = {
            "compile_s": side["compile_s"],
            "first_call_s": side["first_call_s"],
            "train_s": side["train_s"],
            "env_steps": config.num_logs * chunk,
            "env_steps_per_s": config.num_logs * chunk / side["train_s"],
            "final_success": side["curve"][-1]["success"],
            "late_success": late_success(side["curve"]),
            "time_to_threshold_s": None if reached is None else reached["train_s"],
            "steps_to_threshold": None if reached is None else reached["env_steps"],
            "curve": side["curve"],
        }
    final = _greedy_success(trainer, final_episodes, FINAL_EPISODES_SEED)
    for side in sides:
        params = side["q_params"](side["state"])
        rate = final(side["apply"], params) if final_episodes else None
        out[side["name"]]["final_eval_success"] = rate
    ours, theirs = (out[s["name"]] for s in sides)
    # equal success: rejax's best of the run, and when each side first reached it
    peer_best = max(p["success"] for p in theirs["curve"])
    for side in (ours, theirs):
        reached = first_reaching(side["curve"], peer_best)
        side["time_to_peer_best_s"] = None if reached is None else reached["train_s"]
    t_ours, t_theirs = ours["time_to_peer_best_s"], theirs["time_to_peer_best_s"]
    params = sides[0]["q_params"](sides[0]["state"])
    return {
        "algo": config.algo,
        "env": config.env,
        "hidden_sizes": list(config.hidden_sizes),
        "network_weights": sum(x.size for x in jax.tree.leaves(params)),
        "threshold": threshold,
        "eval_episodes": eval_episodes,
        "final_eval_episodes": final_episodes or None,
        "seed": seed,
        "peer_compiler_options": peer_options,
        "sides": out,
        "wall_time_ratio": theirs["train_s"] / ours["train_s"],
        "peer_best_success": peer_best,
        "equal_success_ratio": None if t_ours is None else t_theirs / t_ours,
    }


def after_first_ratio(sides: Iterable[dict[str, Any]]) -> float | None:
    """rejax / ours in train time over the intervals after each side's first, from the two
    sides' curves (ours first); None for runs of one interval."""
    seconds = []
    for side in sides:
        curve = side.get("curve", [])
        if len(curve) < 2:
            return None
        seconds.append(curve[-1]["train_s"] - curve[0]["train_s"])
    ours, theirs = seconds
    return theirs / ours


def ratio_text(value: float | None) -> str:
    """A ratio rejax / ours, "n/a" where there is none."""
    return "n/a" if value is None else f"{value:.2f}x"


def late_success(curve: list[dict[str, Any]]) -> float:
    """The mean success of the last ``LATE_FRACTION`` of a curve's points (at least one)."""
    late = curve[-max(1, math.ceil(len(curve) * LATE_FRACTION)) :]
    return sum(p["success"] for p in late) / len(late)


def first_reaching(curve: list[dict[str, Any]], success: float) -> dict[str, Any] | None:
    """The first point of a success curve at or above ``success`` (None: never)."""
    return next((p for p in curve if p["success"] >= success), None)


def table(result: dict[str, Any]) -> str:
    thr = result["threshold"]
    lines = [
        f"| trainer | compile s | first call s | train s | env steps/s | final greedy success "
        f"| mean success, last quarter | train s to success >= {thr:g} |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, s in result["sides"].items():
        t = s["time_to_threshold_s"]
        reached = "not reached" if t is None else f"{t:.1f} ({s['steps_to_threshold']:,} steps)"
        lines.append(
            f"| {name} | {s['compile_s']:.1f} | {seconds_text(s.get('first_call_s'))} "
            f"| {s['train_s']:.1f} | "
            f"{s['env_steps_per_s']:,.0f} | {s['final_success']:.3f} | "
            f"{success_text(s.get('late_success'))} | {reached} |"
        )
    lines.append(
        f"\nWall-time ratio rejax / ours: **{result['wall_time_ratio']:.2f}x**; over the "
        f"intervals after each side's first: "
        f"{ratio_text(after_first_ratio(result['sides'].values()))}"
    )
    lines.append(f"\n{equal_success(result)}")
    if result.get("final_eval_episodes"):
        lines.append(f"\n{final_evaluation(result)}")
    if result.get("peer_compiler_options"):
        lines.append("\nRejax compiled with our XLA options (`jaxnav.train.COMPILER_OPTIONS`).")
    return "\n".join(lines)


def final_evaluation(result: dict[str, Any]) -> str:
    """One line: each side's final policy on the final evaluation's episodes, with the
    binomial standard error of the larger one."""
    n = result["final_eval_episodes"]
    rates = [s["final_eval_success"] for s in result["sides"].values()]
    error = max(math.sqrt(p * (1 - p) / n) for p in rates)
    return (
        f"Final policies on {n:,} fresh episodes (other than the checks'): jaxnav "
        f"{rates[0]:.3f} / rejax {rates[1]:.3f} (standard error at most {error:.3f})"
    )


def equal_success(result: dict[str, Any]) -> str:
    """One line: when each side first reached the best success rejax reached."""
    ours, theirs = result["sides"].values()
    t_ours, t_theirs = ours["time_to_peer_best_s"], theirs["time_to_peer_best_s"]
    ratio = result["equal_success_ratio"]
    head = f"At equal success (rejax's best, {result['peer_best_success']:.3f}): train s "
    if ratio is None:
        return head + f"jaxnav never reached it / rejax {t_theirs:.1f}"
    return head + f"jaxnav {t_ours:.1f} / rejax {t_theirs:.1f}, rejax / ours **{ratio:.2f}x**"


def seconds_text(value: float | None) -> str:
    """Seconds, "n/a" where they were not recorded (``first_call_s`` in older results)."""
    return "n/a" if value is None else f"{value:.2f}"


def success_text(value: float | None) -> str:
    """A success rate, "n/a" where it was not recorded (``late_success`` in older results)."""
    return "n/a" if value is None else f"{value:.3f}"


def success_each(result: dict[str, Any], field: str) -> str:
    """A success of each side, "jaxnav / rejax"."""
    return " / ".join(success_text(s.get(field)) for s in result["sides"].values())


def seconds_each(result: dict[str, Any], field: str) -> str:
    """A time of each side, "jaxnav / rejax" ("-" where that side never reached it)."""
    return " / ".join(
        "-" if s[field] is None else f"{s[field]:.1f}" for s in result["sides"].values()
    )


def final_count(results: list[dict[str, Any]]) -> str:
    """The final evaluation's episode count of ``results`` ("N" where runs differ or have
    none)."""
    counts = {r.get("final_eval_episodes") for r in results}
    count = counts.pop() if len(counts) == 1 else None
    return "N" if count is None else f"{count:,}"


def side_stats(
    runs: list[dict[str, Any]],
    field: str,
    stat: Callable[[list[float]], float] = statistics.fmean,
) -> list[float] | None:
    """Each side's ``stat`` of ``field`` over ``runs`` (jaxnav first); None where a run did
    not record it."""
    sides = [[list(r["sides"].values())[i].get(field) for r in runs] for i in (0, 1)]
    if any(v is None for side in sides for v in side):
        return None
    return [stat(side) for side in sides]


def pair_text(values: list[float] | None) -> str:
    """Each side's success, jaxnav / rejax, as the tables show it; "n/a" where not recorded."""
    return "n/a" if values is None else " / ".join(map(success_text, values))


def mean_row(runs: list[dict[str, Any]]) -> str:
    """``summary``'s row of means over several seeds' runs of one network."""

    def success(field: str) -> str:
        return pair_text(side_stats(runs, field))

    train_s = side_stats(runs, "train_s")
    ratio = sum(r["wall_time_ratio"] for r in runs) / len(runs)
    after_first = [after_first_ratio(r["sides"].values()) for r in runs]
    after_first_mean = None if None in after_first else sum(after_first) / len(runs)
    return (
        f"| {'-'.join(map(str, runs[0]['hidden_sizes']))} | mean of {len(runs)} | "
        f"| {train_s[0]:.1f} | {train_s[1]:.1f} | {ratio:.2f}x | {ratio_text(after_first_mean)} "
        f"| {success('final_success')} | {success('late_success')} "
        f"| {success('final_eval_success')} | | | | |"
    )


def runs_by_network(results: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """``results``' runs grouped by network, in the order each network first appears."""
    by_network: dict[tuple[int, ...], list[dict[str, Any]]] = {}
    for r in results:
        by_network.setdefault(tuple(r["hidden_sizes"]), []).append(r)
    return list(by_network.values())


def summary(results: list[dict[str, Any]]) -> str:
    """One row per run of ``measure`` results: train time of each side, the ratio, and the
    successes; then, for a network run with several seeds, a row of their means."""
    thr = results[0]["threshold"]
    lines = [
        "| network | seed | weights | jaxnav train s | rejax train s | rejax / ours "
        "| rejax / ours after the first interval "
        "| final success, jaxnav / rejax | mean success of the last quarter, jaxnav / rejax "
        f"| final policy on {final_count(results)} fresh episodes, jaxnav / rejax "
        f"| train s to success >= {thr:g}, jaxnav / rejax | rejax's best success "
        "| train s to it, jaxnav / rejax | rejax / ours at equal success |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        ours, theirs = r["sides"].values()
        ratio = r["equal_success_ratio"]
        lines.append(
            f"| {'-'.join(map(str, r['hidden_sizes']))} | {r['seed']} "
            f"| {r['network_weights']:,} | {ours['train_s']:.1f} | {theirs['train_s']:.1f} "
            f"| {r['wall_time_ratio']:.2f}x "
            f"| {ratio_text(after_first_ratio(r['sides'].values()))} "
            f"| {success_each(r, 'final_success')} "
            f"| {success_each(r, 'late_success')} | {success_each(r, 'final_eval_success')} "
            f"| {seconds_each(r, 'time_to_threshold_s')} "
            f"| {r['peer_best_success']:.3f} | {seconds_each(r, 'time_to_peer_best_s')} "
            f"| {'jaxnav did not reach it' if ratio is None else f'{ratio:.2f}x'} |"
        )
    networks = runs_by_network(results)
    lines += [mean_row(runs) for runs in networks if len(runs) > 1]
    notes = [note(runs) for runs in networks for note in (final_difference, final_spread)]
    return "\n".join(lines + [f"\n{note}" for note in notes if note])


def _final_pairs(runs: list[dict[str, Any]]) -> list[list[float]] | None:
    """Each run's (jaxnav, rejax) final-policy success, for several seeds' runs that all
    have a final evaluation; None otherwise (one seed has no spread)."""
    pairs = [[s.get("final_eval_success") for s in r["sides"].values()] for r in runs]
    counts = [r.get("final_eval_episodes") for r in runs]
    if len(runs) < 2 or None in counts or any(None in p for p in pairs):
        return None
    return pairs


def standard_error(values: list[float]) -> float | None:
    """The standard error of the mean of ``values`` (one a seed): what another set of seeds
    would move it by; None for fewer than two."""
    if len(values) < 2:
        return None
    return float(scipy.stats.sem(values))


def final_difference_stats(runs: list[dict[str, Any]]) -> tuple[float, float, float] | None:
    """For several seeds' runs of one network with final evaluations: the mean of jaxnav's
    minus rejax's final-policy success, its standard error over the seeds (what another set
    of seeds would move) and that of the episodes alone; None otherwise."""
    pairs = _final_pairs(runs)
    if pairs is None:
        return None
    counts = [r["final_eval_episodes"] for r in runs]
    k = len(runs)
    diffs = [ours - theirs for ours, theirs in pairs]
    mean = sum(diffs) / k
    over_seeds = standard_error(diffs)
    episodes = (
        math.sqrt(sum(p * (1 - p) / n for pair, n in zip(pairs, counts, strict=True) for p in pair))
        / k
    )
    return mean, over_seeds, episodes


def signed(value: float) -> str:
    """A difference of successes to 3 places with its sign ("+0.000" for a rounded -0.0)."""
    return f"{round(value, 3) + 0.0:+.3f}"


def final_difference(runs: list[dict[str, Any]]) -> str | None:
    """``final_difference_stats`` as one line; None where there are none."""
    stats = final_difference_stats(runs)
    if stats is None:
        return None
    mean, over_seeds, episodes = stats
    network = "-".join(map(str, runs[0]["hidden_sizes"]))
    return (
        f"Final policies, jaxnav minus rejax, network {network} over {len(runs)} seeds: "
        f"{signed(mean)} (standard error over the seeds {over_seeds:.3f}; of the episodes "
        f"alone {episodes:.3f})"
    )


def final_spread(runs: list[dict[str, Any]]) -> str | None:
    """One line for several seeds' runs of one network with final evaluations: each side's
    median, interquartile mean and range of final-policy success over the seeds, where the
    mean alone hides whether one side is ahead on most seeds or behind on one; None
    otherwise."""
    if _final_pairs(runs) is None:
        return None

    def each(stat: Callable[[list[float]], float]) -> str:
        return pair_text(side_stats(runs, "final_eval_success", stat))

    network = "-".join(map(str, runs[0]["hidden_sizes"]))
    return (
        f"Final policies of network {network} over its {len(runs)} seeds, jaxnav / rejax: "
        f"median {each(statistics.median)}, interquartile mean {each(iqm)}, "
        f"lowest {each(min)}, highest {each(max)}"
    )
