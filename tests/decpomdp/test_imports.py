"""decpomdp sees perception only through its protocol: it never imports classifiers or hbni_pyro."""

import subprocess
import sys


def test_decpomdp_does_not_import_perception_packages():
    code = (
        "import sys, decpomdp, decpomdp.dpomdp, decpomdp.gdice, decpomdp.baselines;"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('classifiers', 'hbni_pyro')];"
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
