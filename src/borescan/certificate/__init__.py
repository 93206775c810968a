"""Calibration certificates.

The documents are ``certificate.json``, ``certificate.pdf``, ``certificate.dcc.xml`` and ``residuals.png``.

Written into ``results_root/calibration/<device_id>/<calibration_id>/`` (``outputs.md``).

Content (ISO/IEC 17025:2017 7.8.2.1 and 7.8.4.1): title; issuing laboratory, its address and
accreditation statement; place of calibration; unique identification (the calibration id) and
"page x of y" on every page; customer; method; the item (device with its sensors as a table);
dates of calibration and of issue; conditions with their uncertainties; results with the
expanded uncertainty U, coverage factor k and coverage probability; the GUM uncertainty budget
(every input: estimate, standard uncertainty, distribution, degrees of freedom, sensitivity,
contribution); traceability (the reference gauge, its certificate, issuer and validity); the
night's verifications with the decision rule and the conformity statement; the recalibration
due date; the signatory. The laboratory's name, address, accreditation, customer and signatory
come from the config's ``laboratory`` section; its defaults are placeholders that say so.

``certificate.json`` carries the same content; its administrative and result parts use the
element names of the PTB Digital Calibration Certificate (DCC 3.x: ``administrativeData``,
``coreData``, ``uniqueIdentifier``, ``beginPerformanceDate``, ``calibrationLaboratory``,
``respPersons``, ``customer``, ``statements``, ``measurementResults``, ``usedMethods``,
``measuringEquipments``, ``influenceConditions``, ``results``; D-SI ``expandedUnc`` with
``uncertainty``, ``coverageFactor``, ``coverageProbability``, ``distribution``) where they exist.

Regenerating from the same inputs gives byte-identical files: JSON with sorted keys and floats
rounded to 12 significant digits; PDF without CreationDate/ModDate/Producer/Creator; PNG without
the Software key; figures built on fresh ``matplotlib.figure.Figure`` objects (no pyplot state).
The issue date is therefore not the wall clock at writing: it is the UTC date the workflow first
processed the night, kept in the night's record (:func:`borescan.night_config.first_processed`), and
the certificate says so.

Modules: :mod:`.content` (folders, dates, conditions, JSON numbers), :mod:`.admin` (the administrative part
shared by both devices), :mod:`.tri` and :mod:`.rod` (each device's certificate.json; the rod's PDF pages and
residuals), :mod:`.layout`, :mod:`.pages`, :mod:`.budget_pages` (the PDF), :mod:`.write` (the documents),
:mod:`.dcc`, :mod:`.dcc_results`, :mod:`.dcc_elements` (certificate.dcc.xml).
"""

from borescan.certificate.content import (
    CERTIFICATE_FORMAT,
    PLACEHOLDER,
    calibration_conditions,
    certificate_dates,
    certificate_dir,
    certificate_night_dir,
)
from borescan.certificate.rod import rod_certificate_dict, rod_pose_residuals
from borescan.certificate.tri import certificate_dict, device_model_text, rho_sign_part
from borescan.certificate.write import write_certificate, write_certificate_files, write_rod_certificate

__all__ = [
    "CERTIFICATE_FORMAT",
    "PLACEHOLDER",
    "calibration_conditions",
    "certificate_dates",
    "certificate_dict",
    "certificate_dir",
    "certificate_night_dir",
    "device_model_text",
    "rho_sign_part",
    "rod_certificate_dict",
    "rod_pose_residuals",
    "write_certificate",
    "write_certificate_files",
    "write_rod_certificate",
]
