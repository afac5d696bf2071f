"""Stored runs as Bluesky runs in a Tiled catalog: what ``bench serve`` serves.

Two ideas, one module each: :mod:`bench.catalog.documents` turns a stored run into the Bluesky
documents of a run (:func:`run_documents`, its start uid :func:`run_uid` and ``scan_id``
:func:`scan_ids`); :mod:`bench.catalog.sync` runs the Tiled server and keeps its catalog in step
with the store (:class:`CatalogServer`, :func:`served_state`). The public names are re-exported here.
"""

from __future__ import annotations

from bench.catalog.documents import RUN_UID_NAMESPACE, STATUS_EXIT, run_documents, run_uid, scan_ids
from bench.catalog.sync import CatalogServer, init_catalog, served_state

__all__ = ["run_documents", "run_uid", "scan_ids", "init_catalog", "CatalogServer", "STATUS_EXIT",
           "RUN_UID_NAMESPACE", "served_state"]
