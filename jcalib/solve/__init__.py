"""The engine: problem graph, block-sparse Levenberg–Marquardt, covariance, implicit differentiation.

Public API::

    Variable(name, manifold, value, fixed=False, prior_mean=None, prior_sqrt_info=None,
             eliminate=False, coord_names=None, entry_label=None)
    FactorGroup(name, fn, args, indices, observations=None, sigma=1.0, sqrt_weight=None, loss=None,
                chunk=None, jacobian=None)
    Problem(variables, factors)
    solve(problem, x0=None, options=SolveOptions(), pad=True, raise_on_unobservable=True) -> Solution
    solve_many(problems, options) -> list[Solution]           # one vmapped jit call
    lm_solve(problem, options) -> RawSolution                   # pure; jit / vmap it yourself
    covariance(solution, name, index=None, noise="a_posteriori") -> (d, d) | (num·d, num·d)
    propagate(solution, fn, noise="a_posteriori") -> (p, p)
    solve_differentiable(problem, options) -> values            # implicit-function-theorem VJP
"""

from jcalib.solve.covariance import covariance, propagate
from jcalib.solve.implicit import solve_differentiable
from jcalib.solve.lm import (
    RawSolution,
    Solution,
    SolveOptions,
    Status,
    lm_solve,
    solve,
    solve_many,
    stack_problems,
)
from jcalib.solve.manifolds import SE3, SO3, Euclidean
from jcalib.solve.problem import FactorGroup, Problem, Variable, batch_width, bucket_size, pad_problem

__all__ = [
    "SE3",
    "SO3",
    "Euclidean",
    "FactorGroup",
    "Problem",
    "RawSolution",
    "Solution",
    "SolveOptions",
    "Status",
    "Variable",
    "batch_width",
    "bucket_size",
    "covariance",
    "lm_solve",
    "pad_problem",
    "propagate",
    "solve",
    "solve_differentiable",
    "solve_many",
    "stack_problems",
]
