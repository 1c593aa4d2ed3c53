"""mantis_sim.studies.shared.blas: one BLAS thread for every BLAS library a simulating process
uses."""
import subprocess
import sys

CHECK = '''
from mantis_sim.studies.shared.blas import one_blas_thread
one_blas_thread()
import scipy.linalg  # as an implicit solver's first strike does, after the limit
from threadpoolctl import threadpool_info
blas = [(i['filepath'], i['num_threads']) for i in threadpool_info() if i['user_api'] == 'blas']
print(len(blas), all(threads == 1 for _, threads in blas), blas)
'''


def test_the_limit_reaches_scipy_s_own_blas_loaded_after_it():
    """numpy and scipy.linalg each bring an OpenBLAS; a serial sweep limited numpy's alone and
    ran its LU on two threads, giving other last digits than a Dask worker's."""
    done = subprocess.run([sys.executable, '-c', CHECK], capture_output=True, text=True,
                          check=True)
    count, all_one, _ = done.stdout.split(' ', 2)
    assert int(count) >= 2, done.stdout        # numpy's and scipy's
    assert all_one == 'True', done.stdout
