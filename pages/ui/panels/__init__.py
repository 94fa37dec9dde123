"""The larger parts of the Data page (upload, simulator, project, instruments, MSL files,
foreign tables through a column mapping) and of the Compensate page (task-specific
uncertainty), each a function the page calls where the part goes."""

__all__ = ["instruments", "mapping", "msl", "project", "simulate", "task", "upload"]
