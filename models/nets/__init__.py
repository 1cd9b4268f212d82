"""Neural networks: the GraphSAGE bisection GNN (torch and its numpy twin) and the A2C actor-critic.
Imports models.graph only; imported by models.partition and models.learn."""
