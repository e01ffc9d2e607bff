"""The paper's studies built on the driver: strong and weak convergence (`convergence`) and
calibration of a noise to observed statistics (`calibrate`)."""
