"""The resume journal of a diagnosis: :class:`FitJournal`, every finished candidate fit kept on
disk, so that an interrupted ``odomgym diagnose --resume`` goes on where it stopped.

A matter of files, not of statistics, hence apart from the rounds that fill it
(:mod:`odomgym.diagnose.rounds`): it knows a fit only by the SHA-256 of its job
(:meth:`odomgym.diagnose.fit.FitJob.key_parts`), odomgym's version and :data:`ARITHMETIC`, and
the command line (:mod:`odomgym.cli.diagnose`) makes it, resumes from it and clears it once the
report is written.
"""

from __future__ import annotations

import hashlib
import pickle
import shutil
from pathlib import Path

from odomgym.diagnose.fit import CandidateFit, FitJob
from odomgym.io import atomic_write_bytes

__all__ = ["ARITHMETIC", "FitJournal"]

ARITHMETIC = 4
"""Raised whenever a change moves the fitted numbers (not just the speed) within one odomgym
version, so a journal written before it is not resumed into a report after it. 2: the BLAS
libraries on one thread during a diagnosis (the last digits of every fit moved) and the open-loop
gate's nested fits (:func:`odomgym.diagnose.gate.fit_nested`). 3: the clock fitted beside
backlash, floor bumps among the first round's candidates and their fit from the partner as
given (issue 42). 4: the systematic fits' tolerance (``fit.LEAST_SQUARES_FTOL``, issue 44)."""


class FitJournal:
    """The candidate fits a diagnosis has finished, one file each, so that an interrupted
    diagnosis (``odomgym diagnose --resume``) goes on where it stopped.

    A fit is a deterministic function of its job (the fit runs, the current model and sensor
    noise, the candidate's and nuisance's names, the folds), so a fit is stored under the
    SHA-256 of the pickled job, odomgym's version and :data:`ARITHMETIC`, and a resumed
    diagnosis is identical to an uninterrupted one (tests/test_bench_resume.py). Each file is
    written whole (a temporary file renamed). A changed dataset or setting only misses the
    stored fits. The files are pickles: resume only from a journal you wrote. An effect is
    known by its name: after changing the code of an effect you registered, start afresh
    rather than resume.
    """

    def __init__(self, folder: str | Path, *, resume: bool = False) -> None:
        self.folder = Path(folder)
        self.reused = 0
        self.recorded: set[str] = set()  # fits this diagnosis wrote or has counted
        if not resume:
            self.clear()

    def key(self, job: FitJob) -> str:
        """The file name of ``job``'s fit: the hash of its :meth:`FitJob.key_parts`."""
        from odomgym import __version__

        parts = (__version__, ARITHMETIC, job.key_parts())
        return hashlib.sha256(pickle.dumps(parts, protocol=5)).hexdigest()

    def get(self, key: str) -> CandidateFit | None:
        """The stored fit, or ``None`` (none stored, or a file that does not load)."""
        path = self.folder / f"{key}.pkl"
        try:
            fit = pickle.loads(path.read_bytes())
        except FileNotFoundError:
            return None
        except Exception:  # a damaged entry (any unpickling error) is refitted, not fatal
            path.unlink(missing_ok=True)
            return None
        if not isinstance(fit, CandidateFit):
            return None
        if key not in self.recorded:  # a fit this diagnosis made is found, not resumed
            self.reused += 1
            self.recorded.add(key)  # counted once, however often asked for
        return fit

    def record(self, key: str, fit: CandidateFit) -> None:
        """Store ``fit`` under ``key`` (a stage of a later round may ask for the same fit:
        floor bumps are scored among the first stage's candidates and again in the noise
        stage)."""
        self.recorded.add(key)
        atomic_write_bytes(self.folder / f"{key}.pkl", pickle.dumps(fit, protocol=5))

    def clear(self) -> None:
        """Forget every stored fit (after a finished diagnosis, or at a fresh start)."""
        shutil.rmtree(self.folder, ignore_errors=True)
