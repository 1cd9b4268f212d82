"""Quality of an agglomeration: 2D/3D shape metrics, inscribed and enclosing balls, box measures,
partition statistics, summaries and plots. Imports mesh and graph; imported by hierarchy and the pipeline."""
