"""jaxnav: mobile-robot navigation with deep RL, end to end in JAX."""

from jaxnav.environment import Environment, EnvParams, EnvState
from jaxnav.registration import env_config, make, registered_envs

__version__ = "0.1.0"
__all__ = ["Environment", "EnvParams", "EnvState", "env_config", "make", "registered_envs"]
