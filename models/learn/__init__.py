"""Making data and training the shipped models: test-mesh generation, data sets, GNN and A2C training.
Imports everything below the pipeline; imported only by the CLI."""
