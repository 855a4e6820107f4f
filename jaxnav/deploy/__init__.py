"""Running an exported jaxnav policy off the simulator, with numpy alone (no JAX import).

- ``jaxnav.deploy.policy``: ``Policy.load("policy.npz")``, its Q-values and greedy actions
  (a plain-numpy forward pass of the network ``python -m jaxnav.export`` wrote) and its
  metadata (observation layout, actions, sensors, env).
- ``jaxnav.deploy.sensors``: a robot's lidar scan, pose and goal (and a planner's waypoint)
  turned into the policy's observation, frames stacked as the simulator stacks them.

- ``jaxnav.deploy.planner``: waypoints on a map for a robot of a given radius (walls inflated
  by it plus a margin), the simulator's own planner.
- ``jaxnav.deploy.lidar_map``: ``LidarMap``, the robot's own map from its lidar, the
  simulator's, for a policy trained with its waypoint from it (``lidar_map``): no map needed.
- ``jaxnav.deploy.navigator``: ``Navigator``, the whole loop in one object: policy file, map,
  pose, scan and goal in, action out.

They need only numpy and the standard library: copy them beside the npz onto a robot.
"""
