"""c_stderr_silenced: what native code writes to file descriptor 2 inside the block is discarded, and the stream is
restored after it."""

import subprocess
import sys


def test_native_writes_to_stderr_are_discarded_inside_the_block_only():
    code = ("import os; from prismstereo.quiet import c_stderr_silenced\n"
            "with c_stderr_silenced():\n    os.write(2, b'hidden\\n')\n"
            "os.write(2, b'shown\\n')\n"
            "try:\n    with c_stderr_silenced():\n        raise ValueError('passes')\nexcept ValueError:\n"
            "    os.write(2, b'restored\\n')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stderr == "shown\nrestored\n"
