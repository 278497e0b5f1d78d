"""Rendering beyond one process: series of frames over a Dask cluster (series.py) and Blender
animations over the same cluster (blender_frames.py). Imports core and io; imported by the CLI
only (`hovr render-series`). Needs dask.distributed, imported only where a cluster is used."""
