"""Running an exported jaxnav policy off the simulator, with numpy alone (no JAX import).

- ``jaxnav.deploy.policy``: ``Policy.load("policy.npz")``, its Q-values and greedy actions
  (a plain-numpy forward pass of the network ``python -m jaxnav.export`` wrote) and its
  metadata (observation layout, actions, sensors, env).
- ``jaxnav.deploy.sensors``: a robot's lidar scan, pose and goal (and a planner's waypoint)
  turned into the policy's observation, frames stacked as the simulator stacks them.

Both files need only numpy and the standard library: copy them beside the npz onto a robot.
"""
