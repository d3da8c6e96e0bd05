"""The README's Python example runs as written."""

import os
import re

from test_lanealign import DATA, ROOT, needs_data


def test_the_readme_example_runs(tmp_path, capsys):
    needs_data()
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert blocks, "README has a python block"
    checkout = tmp_path / "main"
    checkout.mkdir()
    (tmp_path / "shared").symlink_to(DATA.parent)
    cwd = os.getcwd()
    os.chdir(checkout)
    try:
        for block in blocks:
            exec(compile(block, "README.md", "exec"), {})
    finally:
        os.chdir(cwd)
    mean = float(capsys.readouterr().out.splitlines()[0])
    assert 0 < mean < 1.0, mean
