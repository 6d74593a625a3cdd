"""The scan directory (format `scanner.scan/1`) and what it records: the manifest (configuration,
planned views, camera model, status), one folder per capture written atomically, and results
folders that never replace an earlier result. Read by the scan, the reconstruction and every
command that opens a saved scan."""
