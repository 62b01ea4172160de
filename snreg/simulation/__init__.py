"""The thesis' studies on simulated data: registration (§5.4, on a synthetic or supplied cohort), tracking
(§5.2, Table 4) and IMU (§5.3, Fig. 19), their statistics and report, and `snreg bench`."""

from snreg.simulation.cohort import Patient, load_cohort, synthetic_cohort
from snreg.simulation.report import markdown_report, write_report
from snreg.simulation.study import StudyConfig, StudyResult, run_study

__all__ = ["Patient", "load_cohort", "synthetic_cohort", "StudyConfig", "StudyResult", "run_study",
           "markdown_report", "write_report"]
