"""The README's Python quickstart runs as printed, and the README stays short with its two commands first."""

import re
from pathlib import Path

import torch

from prismstereo.threads import torch_threads

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_starts_with_the_two_commands_and_stays_short():
    text = README.read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S).group(1).strip().splitlines()
    assert [line.split()[:2] for line in block] == [["make", "demo"], ["make", "test"]]
    assert text.index("make demo") < 200 and len(text.encode()) < 6000
    for link in re.findall(r"\]\((docs/[^)]+)\)", text):
        assert (README.parent / link).exists(), link


def test_readme_python_quickstart_runs(capsys):
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    with torch_threads(torch.get_num_threads()):  # whatever the code sets, the count is restored after it
        exec(compile(code, "README.md", "exec"), {})
    assert "torch.Size([1, 1, 768, 512])" in capsys.readouterr().out
