"""Place pose4d_ros's executables where `ros2 run` looks for them: <prefix>/lib/pose4d_ros/.

`pip install .` installs console scripts into <prefix>/bin and ignores setup.cfg's
install_scripts, so this copies each console script of the installed distribution into
<prefix>/lib/pose4d_ros/ (colcon builds do this by themselves). Stale executables that are no
longer entry points are removed.
"""

import os
import shutil
import sys
from importlib.metadata import distribution
from pathlib import Path

PACKAGE = 'pose4d_ros'


def main() -> int:
    prefix = Path(sys.prefix)
    names = {ep.name for ep in distribution(PACKAGE).entry_points if ep.group == 'console_scripts'}
    target = prefix / 'lib' / PACKAGE
    target.mkdir(parents=True, exist_ok=True)
    for stale in set(os.listdir(target)) - names:
        (target / stale).unlink()
    for name in sorted(names):
        source = prefix / 'bin' / name
        if not source.is_file():
            print(f'error: console script {source} is missing', file=sys.stderr)
            return 1
        tmp = target / f'.{name}.tmp'
        shutil.copy2(source, tmp)
        tmp.chmod(0o755)
        tmp.replace(target / name)
    print(f'{len(names)} executables in {target}: {", ".join(sorted(names))}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
