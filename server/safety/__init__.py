"""The center's safety functions: separation between vehicles' planned paths, and warnings."""
