"""`import jaxpile` loads only the jax-md modules it uses (jaxpile/_jax_md.py),
and jax-md stays whole for a user who imports it after jaxpile."""

import subprocess
import sys


def test_import_jaxpile_leaves_the_rest_of_jax_md_unloaded_but_one_attribute_away():
    code = ("import sys, jaxpile\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('jax_md'))\n"
            "assert 'jax_md.energy' not in loaded and 'jax_md.rigid_body' not in loaded, loaded\n"
            "import jax_md\n"
            "assert callable(jax_md.energy.soft_sphere) and callable(jax_md.simulate.nve)\n"
            "from jax_md import quantity\n"
            "assert callable(quantity.force)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
