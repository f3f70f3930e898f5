"""Outputs: the atomic writer, run files (summary, fields), VTU and rerun recordings.
Imports nothing from ``planning``, ``mujoco``, ``studies`` or ``cli``."""

from .atomic import atomic_write_bytes, atomic_write_json, atomic_write_npz, prepare_output_dir

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_npz", "prepare_output_dir"]
