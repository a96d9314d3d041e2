"""Utilities: atomic checkpoints, data-only memmap folders, checkpointed recipe stages, devices."""

from simdist.utils.atomic import atomic_path, write_json_atomic, write_text_atomic
from simdist.utils.checkpoint import (CorruptCheckpointError, CorruptFileError, load_checkpoint,
                                      save_atomic)
from simdist.utils.device import (device_argument, module_device, move_to_device,
                                  resolve_device)
from simdist.utils.memmap import CorruptDataError, folder_manifest, load_memmap, save_memmap
from simdist.utils.sealed import EditedRecordError, read_run_json, write_run_json
from simdist.utils.stages import (FolderInUseError, RunFolderError, StageRunner, iter_jobs,
                                  read_json, read_stage_record, run_jobs)

__all__ = ["load_checkpoint", "save_atomic", "StageRunner", "run_jobs", "iter_jobs",
           "device_argument", "module_device", "move_to_device", "resolve_device", "CorruptDataError",
           "folder_manifest", "load_memmap", "save_memmap", "atomic_path", "write_json_atomic",
           "write_text_atomic", "CorruptCheckpointError", "CorruptFileError", "read_json",
           "RunFolderError", "FolderInUseError", "EditedRecordError", "read_stage_record",
           "read_run_json", "write_run_json"]
