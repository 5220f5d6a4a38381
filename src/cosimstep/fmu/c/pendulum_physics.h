/* The physics of one bar of the split double pendulum, shared by all of cosimstep's pendulum
 * FMUs (FMI 2.0 and 3.0 co-simulation, FMI 2.0 model exchange).
 *
 * Include after defining BAR (1: upper bar, 2: lower bar). The expressions keep the evaluation
 * order of cosimstep.models.pendulum._double_accelerations, so with -ffp-contract=off the FMUs
 * round exactly like the Python bar.
 */
#ifndef COSIMSTEP_PENDULUM_PHYSICS_H
#define COSIMSTEP_PENDULUM_PHYSICS_H

#include <math.h>

#if !defined(BAR) || (BAR != 1 && BAR != 2)
#error "define BAR as 1 (upper bar) or 2 (lower bar) before including pendulum_physics.h"
#endif

/* Parameters of the chain, in the order the FMUs store them. */
typedef struct {
    double m1, m2, l1, l2, g;
} PendulumParameters;

/* Angular acceleration of this bar (Lagrange equations of the chain, explicit 2x2 solve). */
static double pendulum_acceleration(const PendulumParameters *p, double t1, double t2, double w1,
                                    double w2) {
    const double mu0 = p->m1 + p->m2, mu1 = p->m2;
    const double c = cos(t1 - t2), s = sin(t1 - t2), s1 = sin(t1), s2 = sin(t2);
    const double a11 = mu0 * p->l1 * p->l1, a12 = mu1 * p->l1 * p->l2 * c;
    const double a22 = mu1 * p->l2 * p->l2;
    const double f1 = -mu1 * p->l1 * p->l2 * s * w2 * w2 - mu0 * p->g * p->l1 * s1;
    const double f2 = mu1 * p->l1 * p->l2 * s * w1 * w1 - mu1 * p->g * p->l2 * s2;
    const double det = a11 * a22 - a12 * a12;
#if BAR == 1
    return (f1 * a22 - a12 * f2) / det;
#else
    return (a11 * f2 - a12 * f1) / det;
#endif
}

/* dx/dt of this bar's state x = (theta, omega) given the other bar's u = (theta, omega). */
static void pendulum_rhs(const PendulumParameters *p, const double x[2], const double u[2],
                         double dx[2]) {
    dx[0] = x[1];
#if BAR == 1
    dx[1] = pendulum_acceleration(p, x[0], u[0], x[1], u[1]);
#else
    dx[1] = pendulum_acceleration(p, u[0], x[0], u[1], x[1]);
#endif
}

#endif /* COSIMSTEP_PENDULUM_PHYSICS_H */
