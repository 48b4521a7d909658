"""The physics core never imports the orchestration (studies, sweeps, store, reports, optimizer).

The core is the chain design -> geometry -> mesh -> mechanics -> electrics and the coupled model that runs it.
Downstream stages (the sensor-model export, reconstruction, gestures) may use the study package's executors.
"""

import subprocess
import sys

CORE = ["latticeopt.design", "latticeopt.layout", "latticeopt.geometry", "latticeopt.mesh", "latticeopt.mesh.grid",
        "latticeopt.mesh.extruded", "latticeopt.mesh.tetwild", "latticeopt.mechanics", "latticeopt.electrics.forward",
        "latticeopt.electrics.jacobian", "latticeopt.coupled"]
ORCHESTRATION = ["study", "optimize", "cli", "recon", "learn", "gestures"]


def test_core_modules_import_no_orchestration():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE) +
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'latticeopt')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    leaked = [m for m in out if len(m.split(".")) > 1 and m.split(".")[1] in ORCHESTRATION]
    assert leaked == []
