"""The engine: problem graph, block-sparse Levenberg–Marquardt, covariances, implicit differentiation.

Public API::

    Variable(name, manifold, value, fixed=False, prior_mean=None, prior_sqrt_info=None,
             eliminate=False, coord_names=None, entry_label=None, constant=False)
    FactorGroup(name, fn, args, indices, observations=None, sigma=1.0, sqrt_weight=None, loss=None,
                chunk=None, jacobian=None)
    Problem(variables, factors)
    solve(problem, x0=None, options=SolveOptions(), pad=True, raise_on_unobservable=True,
          traces=False) -> Solution                         # one compiled function per shape bucket
    solve_many(problems, options, traces=False) -> list[Solution]   # vmapped
    Solution.covariance(name, index=None, noise="a_posteriori"), .joint_covariance(names),
            .propagate(fn), .shared_information(), .information(names), .residuals / .chi2 / .count / .hat per group
    information(problem, names, x0=None) -> (n, n)           # linearised at x0, no iteration
    lm_solve(problem, options) -> RawSolution                # the pure loop; jit / vmap it yourself
    solve_differentiable(problem, options) -> values         # implicit-function-theorem VJP
    enable_compilation_cache()                               # JAX's persistent cache
"""

from jcalib.solve.batch import batch_width, bucket_size, pad_problem, stack_problems
from jcalib.solve.cache import enable_compilation_cache
from jcalib.solve.core import information, reuse_compiled_shapes, solve, solve_many
from jcalib.solve.implicit import solve_differentiable
from jcalib.solve.lm import RawSolution, SolveOptions, Status, lm_solve
from jcalib.solve.manifolds import SE3, SO3, Euclidean
from jcalib.solve.problem import FactorGroup, Problem, Variable, replace
from jcalib.solve.solution import Solution

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
    "enable_compilation_cache",
    "information",
    "lm_solve",
    "pad_problem",
    "reuse_compiled_shapes",
    "replace",
    "solve",
    "solve_differentiable",
    "solve_many",
    "stack_problems",
]
