"""Print the README's set-up commands (the ```bash blocks of its "Set-up" section), in order, one
per line, so that .ci/run runs exactly what a user is told to."""

import re
import sys
from pathlib import Path

text = Path(sys.argv[1]).read_text()
section = re.search(r"^## Set-up\n(.*?)(?=^## )", text, re.S | re.M)
if section is None:
    sys.exit("the README has no '## Set-up' section")
blocks = re.findall(r"```bash\n(.*?)```", section.group(1), re.S)
if len(blocks) != 2:
    sys.exit(f"the README's Set-up has {len(blocks)} bash blocks, not 2")
for block in blocks:
    print(" ".join(line.strip() for line in block.strip().splitlines()))
