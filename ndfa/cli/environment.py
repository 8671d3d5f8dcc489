"""Process settings the `ndfa` command makes before anything imports torch.

OMP_WAIT_POLICY=PASSIVE: torch's OpenMP workers otherwise busy-wait between parallel ops, and on a
machine shared with other busy processes they spin on cores those need while the work waits for
them (the target pass ran 3.2x slower beside one `while True: pass`; docs/speed.md). OpenMP reads
the variable once, when torch loads it, so it is set here, on the command's first import; a value
the user set is kept. (The default NDF runtime, ONNX Runtime, is told not to spin per session:
`ndfa.ndf.runtime`.)
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
