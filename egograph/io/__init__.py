"""Reading and writing the IT3DEgo layout: recordings, calibration, poses, annotations,
detections, results, atomic output."""
