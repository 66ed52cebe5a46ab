"""The gimbal-friction command line: each subcommand parses its arguments, calls one library function, maps errors.

Thin by rule: no model logic here. May import every library folder; nothing imports cli.

The command sets numpy's documented runtime variable ``NUMPY_MADVISE_HUGEPAGE`` to ``0`` unless the user set it,
before anything imports numpy (numpy reads it once, at its import): ``replay`` allocates and frees arrays of
millions of elements, and where the kernel compacts memory synchronously for a huge-page fault
(``/sys/kernel/mm/transparent_hugepage/defrag`` = ``madvise``, a common default) each such allocation stalled in
the kernel — on the 2.19 M-message bag of bench/REPLAY.md this halved the system CPU time (4.4 s to 2.2–2.5 s). The
numbers computed are the same either way.
"""

import os

os.environ.setdefault('NUMPY_MADVISE_HUGEPAGE', '0')
