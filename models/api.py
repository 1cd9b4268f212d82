"""The library's entry points for callers that run whole jobs (the CLI, the Celery worker).

Torch-free at import time: the service imports this module (validation, model cards, mesh
inspection) and must never import torch. Neural partitioners are loaded lazily by name.

Contract:
- inspect_mesh(path, physical_tag=None) -> {"cells", "points", "dim", "cell_types": {name: count},
  "physical_groups": [int], "bbox": [[min...], [max...]]}; raises MeshError.
- validate_params(params, mesh_info=None) -> normalized params dict; raises ParameterError whose
  message names the field. Keys: model, mode, k, nref, target_size, mult_factor, subset (list of
  cell ids), refiner, options {seed, absorb_fraction, hole_policy, physical_tag}.
- run_job(mesh_path, out_dir, params, progress=None, should_cancel=None) -> summary dict
  {"elements", "parts_split", "fragments_absorbed", "timings": {stage: seconds}, "outputs": {kind: filename}}
  writing into out_dir: mesh.vtu, metrics.json, labels.json, preview.png, and for 2D meshes
  lymph.json + lymph.mat. progress(fraction 0..1, stage name) is called along the way;
  should_cancel() returning True stops the job with JobCancelled.
- list_models() -> [{"name", "dimension", "modes", "description", "version"}]
"""

from __future__ import annotations

MODEL_VERSION = "0.1.0"


class JobCancelled(Exception):
    """Raised inside run_job when should_cancel() returned True."""
