"""The training algorithms, one module each behind ``base.Algorithm``; ``ALGOS`` names them
(``TrainConfig.algo``). The training loop (``jaxnav.train``) reads an algorithm only through
this registry."""

from __future__ import annotations

from jaxnav.algos.base import Algorithm
from jaxnav.algos.dqn import DQN
from jaxnav.algos.ppo import PPO
from jaxnav.algos.pqn import PQN

ALGOS: dict[str, type[Algorithm]] = {"dqn": DQN, "pqn": PQN, "ppo": PPO}
