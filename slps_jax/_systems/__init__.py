"""Stochastic Lie–Poisson systems: the general one (`system`: an algebra, a Hamiltonian and its
noise), the analytic special cases (`rigid_body`, `euler_zeitlin`), the noise families
(`noise`), what a method may need of a system (`capabilities`), and the drift's flow
(`flow`; the rigid body's in closed form, `elliptic_flow`)."""
