"""Studies built on the driver: strong and weak convergence (`convergence`), calibration
(`calibrate`), data-driven transport noise (`transport_fit`) and forecast scores (`scores`)."""
