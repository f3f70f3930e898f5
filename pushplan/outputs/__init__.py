"""Outputs: the one atomic writer (``atomic``), output folders as transactions under a
lock (``transaction``), rerun recordings (``recording``, ``recording_scene``,
``recording_read``), VTU files and a small TOML writer.  Imports nothing from ``run``,
``planning``, ``mujoco``, ``studies`` or ``cli``."""

from .atomic import atomic_write_bytes, atomic_write_json, atomic_write_npz, prepare_output_dir

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_npz", "prepare_output_dir"]
