"""The detector stage: the PMT, its dead-time kernels and the records that flow in (Returns) and out (Detections). Pure."""
