"""``python -m virtual.wire._spawned``: run one emulator function in a fresh interpreter.

:class:`~virtual.wire._pty.PipeEmulator` starts its emulators with this module instead of
``multiprocessing``'s *spawn*, which re-imports the parent's ``__main__``: that fails for a script
read from stdin (``python -``: EOFError), re-runs a script without an ``if __name__ ==
"__main__"`` guard, and breaks under IPython/Jupyter. Here the parent writes one pickle to our
stdin -- ``(authkey, cwd, target, head, tail)``, the target a module-level function pickled by
reference -- and we open a ``multiprocessing.connection.Listener`` on 127.0.0.1, announce its
address as one JSON line on stdout, accept the parent's one connection, move to the parent's
working directory (relative paths mean what they meant there) and call
``target(*head, conn, *tail)``. Nothing of the parent's script is ever imported. We exit when
the parent is gone, however it ended (:func:`~virtual.wire._pty.exit_with_parent`).
"""

from __future__ import annotations

import json
import os
import pickle
import sys
from multiprocessing.connection import Listener

from virtual.wire._pty import exit_with_parent

__all__ = ["main"]


def main() -> int:
    exit_with_parent()  # first: a parent killed while we start must not leave us waiting in accept()
    authkey, cwd, target, head, tail = pickle.load(sys.stdin.buffer)
    with Listener(("127.0.0.1", 0), authkey=authkey) as listener:
        host, port = listener.address
        print(json.dumps({"control": f"{host}:{port}"}), flush=True)
        conn = listener.accept()
    os.chdir(cwd)
    target(*head, conn, *tail)
    return 0


if __name__ == "__main__":
    sys.exit(main())
