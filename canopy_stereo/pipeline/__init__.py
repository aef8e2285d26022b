"""End-to-end pipelines over the core: images -> rectified -> disparity -> points."""
