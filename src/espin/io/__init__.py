"""espin's thin I/O layer: HDF5 files of RVEs and results, VTK exports, atomic writes."""
