"""One router per resource: meshes, jobs (and the one-call agglomerate endpoints), models, health."""
