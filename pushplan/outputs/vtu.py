"""VTU files of a run for ParaView: one unstructured grid per step (the deformed
block with its nodal fields) and the ``block.pvd`` series that lists them, each
written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fe_contact import Model, StepReport

from .atomic import atomic_path, atomic_write_bytes, prepare_output_dir

SERIES_FILE = "block.pvd"


def _write_mesh(path: Path, mesh) -> Path:
    """``meshio.write`` to ``path`` atomically (meshio writes to a path only: the
    reserved temporary sibling, then moved into place)."""
    import meshio

    with atomic_path(path) as tmp:
        meshio.write(tmp, mesh, file_format="vtu")
    return path


def _series(reports: list[StepReport], paths: list[Path]) -> bytes:
    """The ``.pvd`` collection: one ``DataSet`` per step, its time the step index."""
    entries = "\n".join(f'    <DataSet timestep="{r.step_index}" file="{p.name}"/>' for r, p in zip(reports, paths, strict=True))
    return (f'<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n{entries}\n'
            "  </Collection>\n</VTKFile>\n").encode()


def write_vtu(model: Model, reports: list[StepReport], folder) -> list[Path]:
    """One ``step_NN.vtu`` per report and the ``block.pvd`` series in ``folder``.

    Points are the deformed positions (m), cells the hex8 elements.  Point data:
    ``displacement`` (m); on the lower face, zero elsewhere: ``reaction`` (world, N),
    ``r_n`` (N), ``pressure`` (Pa), ``slip`` and ``slip_path`` (m), ``gap`` (m);
    ``contact_status`` 0 stick / 1 slip / 2 separated / -1 not a contact node.

    Returns
    -------
    list of Path
        The VTU files, in step order (the series file is not listed).
    """
    import meshio

    folder = prepare_output_dir(folder)
    mesh = model.mesh

    def on_face(values, dtype=float, fill=0.0):
        a = np.full((mesh.n_nodes,) + np.shape(values)[1:], fill, dtype=dtype)
        a[mesh.lower] = values
        return a

    paths = []
    for rep in reports:
        point_data = {
            "displacement": rep.displacement,
            "reaction": on_face(rep.reaction_world),
            "r_n": on_face(rep.reaction_local[:, 0]),
            "pressure": on_face(rep.pressure),
            "slip": on_face(rep.slip),
            "slip_path": on_face(rep.slip_path),
            "gap": on_face(rep.gap),
            "contact_status": on_face(rep.node_status, dtype=np.int32, fill=-1),
        }
        block = meshio.Mesh(mesh.nodes + rep.displacement, [("hexahedron", mesh.elements)], point_data=point_data)
        paths.append(_write_mesh(folder / f"step_{rep.step_index:02d}.vtu", block))
    atomic_write_bytes(folder / SERIES_FILE, _series(reports, paths))
    return paths
