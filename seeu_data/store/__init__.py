"""Storage: atomic Arrow IPC and text writes (arrow_io), schemas (schema), manifests (manifest), posed
frames (posed), contained paths (paths), resumable stages (resume), the output lock (out_lock), the one
JSON reader (json_file), image headers (image_header), the Arrow row of a triple (triple_row) and the one dataset validator (dataset_check)."""
