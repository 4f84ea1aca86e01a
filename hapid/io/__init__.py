"""The only file I/O: run, FRF and model files (npz contracts in docs/contracts.md), CSV and MATLAB .mat.

Every writer validates before it writes and writes atomically (temporary file + rename), so a
bad input never leaves a half-written file. Every reader validates what it read and names the
file and the problem in its error.

* ``_common`` — :class:`FileFormatError`, atomic writes, reading ``.npz``/``.mat``/CSV text.
* ``_run`` — run files (:func:`save_run`, :func:`load_run`).
* ``_frf`` — FRF files, predictive draws and single-impedance FRFs.
* ``_model`` — model, single-impedance model and design files.
* ``_timeseries`` — lab time series (``.npz``, ``.mat``, ``.csv``).
* ``_samples`` — posterior samples (:func:`load_samples` imports :mod:`hapid.samples`
  only when called).
* ``_reports`` — strict JSON, text, CSV tables, bytes, :func:`file_sha256`.
* ``_cache`` — stage-cache entries; ``_kind`` — :func:`file_kind`.
"""

from ._cache import CacheEntry as CacheEntry
from ._cache import load_cache_entry as load_cache_entry
from ._cache import save_cache_entry as save_cache_entry
from ._common import FileFormatError as FileFormatError
from ._frf import COHERENCE_KEYS as COHERENCE_KEYS
from ._frf import IMPEDANCE_CSV_LAYOUT as IMPEDANCE_CSV_LAYOUT
from ._frf import load_frf as load_frf
from ._frf import load_impedance_frf as load_impedance_frf
from ._frf import save_draws as save_draws
from ._frf import save_frf as save_frf
from ._frf import save_impedance_frf as save_impedance_frf
from ._kind import file_kind as file_kind
from ._model import IMPEDANCE_MODEL_KEYS as IMPEDANCE_MODEL_KEYS
from ._model import MODEL_KEYS as MODEL_KEYS
from ._model import DesignFile as DesignFile
from ._model import load_design as load_design
from ._model import load_impedance_model as load_impedance_model
from ._model import load_model as load_model
from ._model import load_model_metadata as load_model_metadata
from ._model import save_design as save_design
from ._model import save_impedance_model as save_impedance_model
from ._model import save_model as save_model
from ._reports import file_sha256 as file_sha256
from ._reports import jsonable as jsonable
from ._reports import save_bytes as save_bytes
from ._reports import save_csv as save_csv
from ._reports import save_json as save_json
from ._reports import save_text as save_text
from ._reports import to_json as to_json
from ._run import load_run as load_run
from ._run import save_run as save_run
from ._samples import load_samples as load_samples
from ._samples import save_samples as save_samples
from ._timeseries import TIMESERIES_CSV_LAYOUT as TIMESERIES_CSV_LAYOUT
from ._timeseries import load_timeseries as load_timeseries
from ._timeseries import save_timeseries as save_timeseries
