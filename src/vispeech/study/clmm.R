# Cumulative-link mixed models for vispeech's study analysis (vispeech.study.clmm runs it):
# R's ordinal::clmm, car::Anova and emmeans, as the thesis analysed its surveys.
#
#   Rscript clmm.R REQUEST.json RESULT.json
#
# REQUEST.json: {"jobs": [JOB, ...]}, each JOB
#   id                 a name, echoed back
#   data               a CSV file (UTF-8, a header row), every value read as text
#   response           the response column: an ordered factor with levels `levels`
#   levels, values     the response's levels, lowest first, and the number each stands for
#                      (for the inferred mean)
#   factors            {column: [levels]}: unordered factors, the first level the reference
#                      (every other column is read as a number)
#   formulas           clmm formulas (clm for one without random terms), tried in order until
#                      one fits (see fit_formula)
#   term               a factor of the formula (or null): its emmeans, Tukey-adjusted pairs,
#                      inferred probability of each response level and inferred mean
#   proportional_odds  a clm formula (or null): nominal_test and scale_test on its fit
# RESULT.json: {"versions": {...}, "jobs": [RESULT, ...]} (see describe_fit).
#
# Exit status 3 with "vispeech-missing-r-packages: NAME ..." on stderr when a package is missing.

needed <- c("ordinal", "car", "emmeans", "jsonlite")
missing <- needed[!vapply(needed, requireNamespace, logical(1), quietly = TRUE)]
if (length(missing)) {
  cat("vispeech-missing-r-packages:", missing, "\n", file = stderr())
  quit(status = 3)
}
suppressPackageStartupMessages({
  library(ordinal)
  library(car)
  library(emmeans)
})

# car::Anova has methods for clm and clmm fits only from car 3.1-2 on; for older car (Debian 12
# has 3.1-1) the default method is given the fixed effects alone, as car 3.1-2 does it.
registerS3method("coef", "fixedAnova", function(object, ...) object$beta)
registerS3method("vcov", "fixedAnova", function(object, ...) {
  b <- names(object$beta)
  class(object) <- class(object)[-1]
  vcov(object)[b, b, drop = FALSE]
})
registerS3method("model.matrix", "fixedAnova", function(object, ...) {
  X <- model.matrix(object$terms, data = model.frame(object), contrasts.arg = object$contrasts)
  keep <- colnames(X) != "(Intercept)"
  structure(X[, keep, drop = FALSE], assign = attr(X, "assign")[keep])
})
wald_anova <- function(m) {
  if (is.null(getS3method("Anova", class(m)[1], optional = TRUE, envir = asNamespace("car")))) {
    class(m) <- c("fixedAnova", class(m))
  }
  Anova(m, type = "II")
}

COND_H_LIMIT <- 1e4  # above this the Hessian is ill-conditioned: the model may be ill defined

num <- function(x) if (length(x) == 0 || is.null(x) || !is.finite(x)) NA_real_ else as.numeric(x)

# Run `expr`, collecting its warnings (as text) instead of printing them.
collecting <- function(expr, sink) {
  withCallingHandlers(expr, warning = function(w) {
    sink(conditionMessage(w))
    invokeRestart("muffleWarning")
  })
}

read_job_data <- function(job) {
  d <- read.csv(job$data, colClasses = "character", check.names = FALSE, na.strings = character(0),
                encoding = "UTF-8")
  d[[job$response]] <- factor(d[[job$response]], levels = unlist(job$levels), ordered = TRUE)
  for (name in names(job$factors)) d[[name]] <- factor(d[[name]], levels = unlist(job$factors[[name]]))
  for (name in setdiff(names(d), c(job$response, names(job$factors)))) d[[name]] <- as.numeric(d[[name]])
  d
}

mixed <- function(m) inherits(m, "clmm")

# The optimiser's verdict: code (0: converged), message, iterations.
optimiser <- function(m) {
  if (mixed(m)) {
    list(code = m$optRes$convergence, message = m$optRes$message, iterations = m$optRes$iterations)
  } else {
    list(code = m$convergence$code, message = m$convergence$messages, iterations = num(m$niter[["outer"]]))
  }
}

# Fit one formula to .vispeech_data (clmm, or clm for a formula without random terms): list(model,
# summary, attempt), `model` NULL when the fit failed. A fit fails when it stops with an error,
# when its optimiser reports no convergence, or when the Hessian gives no finite standard errors.
fit_formula <- function(formula) {
  warns <- character()
  sink <- function(text) warns <<- c(warns, text)
  started <- proc.time()[["elapsed"]]
  f <- as.formula(formula)
  call <- if (grepl("|", formula, fixed = TRUE)) {
    bquote(clmm(.(f), data = .vispeech_data, link = "logit", threshold = "flexible", Hess = TRUE))
  } else {
    bquote(clm(.(f), data = .vispeech_data, link = "logit", threshold = "flexible"))
  }
  m <- tryCatch(collecting(eval(call, globalenv()), sink), error = function(e) e)
  problem <- NULL
  s <- NULL
  if (inherits(m, "error")) {
    problem <- conditionMessage(m)
  } else if (optimiser(m)$code != 0) {
    problem <- paste("the optimiser did not converge:", paste(optimiser(m)$message, collapse = " "))
  } else {
    s <- tryCatch(collecting(summary(m), sink), error = function(e) e)
    if (inherits(s, "error")) {
      problem <- conditionMessage(s)
    } else if (!all(is.finite(s$coefficients[, 2]))) {
      problem <- "the Hessian is not positive definite: no standard errors"
    }
  }
  attempt <- list(formula = formula, error = problem, warnings = as.list(unique(warns)),
                  seconds = proc.time()[["elapsed"]] - started)
  list(model = if (is.null(problem)) m else NULL, summary = s, attempt = attempt)
}

# The first of `formulas` that fits; every attempt is reported.
fit_first <- function(formulas) {
  attempts <- list()
  for (formula in formulas) {
    fit <- fit_formula(formula)
    attempts[[length(attempts) + 1]] <- fit$attempt
    if (!is.null(fit$model)) return(c(fit, list(attempts = attempts)))
  }
  list(model = NULL, summary = NULL, attempts = attempts)
}

coefficient_rows <- function(table, rows, p) {
  lapply(rows, function(i) {
    row <- list(name = rownames(table)[i], estimate = num(table[i, 1]), se = num(table[i, 2]),
                z = num(table[i, 3]))
    if (p) row$p <- num(table[i, 4])
    row
  })
}

random_effects <- function(m) {
  vc <- if (mixed(m)) VarCorr(m) else list()
  sds <- list()
  cors <- list()
  problems <- character()
  for (group in names(vc)) {
    v <- vc[[group]]
    sd <- attr(v, "stddev")
    for (k in seq_along(sd)) {
      sds[[length(sds) + 1]] <- list(group = group, term = names(sd)[k], variance = num(sd[k]^2), sd = num(sd[k]))
    }
    r <- attr(v, "correlation")
    if (!is.null(r) && nrow(r) > 1) {
      for (i in 1:(nrow(r) - 1)) for (j in (i + 1):nrow(r)) {
        cors[[length(cors) + 1]] <- list(group = group, a = rownames(r)[i], b = rownames(r)[j], r = num(r[i, j]))
        if (is.finite(r[i, j]) && abs(r[i, j]) > 0.99) problems <- c(problems, group)
      }
    }
    if (any(sd < 1e-3)) problems <- c(problems, group)
  }
  list(sd = sds, correlations = cors, singular = as.list(unique(problems)))
}

term_summaries <- function(m, d, term, response, values) {
  e <- emmeans(m, as.formula(paste("~", term)), data = d)
  es <- summary(e)
  levels <- as.character(es[[term]])
  emm <- lapply(seq_len(nrow(es)), function(i) {
    list(level = levels[i], emmean = num(es$emmean[i]), se = num(es$SE[i]),
         lower = num(es$asymp.LCL[i]), upper = num(es$asymp.UCL[i]))
  })
  ps <- summary(pairs(e, adjust = "tukey"))
  k <- length(levels)
  ij <- do.call(rbind, lapply(seq_len(k - 1), function(i) cbind(i, (i + 1):k)))
  if (nrow(ps) != nrow(ij)) stop("emmeans gave ", nrow(ps), " pairs of ", k, " levels")
  pairs_out <- lapply(seq_len(nrow(ps)), function(r) {
    list(a = levels[ij[r, 1]], b = levels[ij[r, 2]], estimate = num(ps$estimate[r]), se = num(ps$SE[r]),
         z = num(ps$z.ratio[r]), p = num(ps$p.value[r]))
  })
  prob <- emmeans(m, as.formula(paste("~", response, "|", term)), mode = "prob", data = d)
  pr <- summary(prob)
  answers <- levels(d[[response]])[as.integer(pr[[response]])]  # for clmm fits emmeans labels them 1, 2, ...
  probabilities <- lapply(seq_len(nrow(pr)), function(i) {
    list(level = as.character(pr[[term]][i]), response = answers[i],
         probability = num(pr$prob[i]), se = num(pr$SE[i]), lower = num(pr$asymp.LCL[i]),
         upper = num(pr$asymp.UCL[i]))
  })
  mean_grid <- contrast(prob, method = list(mean = values), by = term)
  ms <- summary(mean_grid, infer = c(TRUE, FALSE))
  means <- lapply(seq_len(nrow(ms)), function(i) {
    list(level = as.character(ms[[term]][i]), mean = num(ms$estimate[i]), se = num(ms$SE[i]),
         lower = num(ms$asymp.LCL[i]), upper = num(ms$asymp.UCL[i]))
  })
  list(emmeans = emm, pairs = pairs_out, probabilities = probabilities, means = means)
}

test_row <- function(table, term) {
  if (is.null(table) || !(term %in% rownames(table))) return(NULL)
  list(df = num(table[term, "Df"]), lrt = num(table[term, "LRT"]), p = num(table[term, "Pr(>Chi)"]))
}

proportional_odds <- function(formula) {
  warns <- character()
  sink <- function(text) warns <<- c(warns, text)
  out <- tryCatch({
    f <- collecting(eval(bquote(clm(.(as.formula(formula)), data = .vispeech_data, link = "logit")), globalenv()),
                    sink)
    nominal <- collecting(nominal_test(f), sink)
    scale <- collecting(scale_test(f), sink)
    terms <- attr(terms(f), "term.labels")
    list(formula = formula,
         nominal = lapply(setNames(terms, terms), function(t) test_row(nominal, t)),
         scale = lapply(setNames(terms, terms), function(t) test_row(scale, t)),
         error = NULL)
  }, error = function(e) list(formula = formula, nominal = NULL, scale = NULL, error = conditionMessage(e)))
  out$warnings <- as.list(unique(warns))
  out
}

describe_fit <- function(fit, job, d) {
  m <- fit$model
  s <- fit$summary
  out <- list(id = job$id, requested = job$formulas[[1]], attempts = fit$attempts)
  last <- fit$attempts[[length(fit$attempts)]]
  if (is.null(m)) {
    out["formula"] <- list(NULL)
    out$error <- last$error
    return(out)
  }
  info <- s$info
  co <- s$coefficients
  nalpha <- length(m$alpha)
  nbeta <- length(m$beta)
  re <- random_effects(m)
  warns <- unlist(last$warnings)
  cond_h <- num(with(eigen(m$Hessian, only.values = TRUE), abs(max(values) / min(values))))
  if (is.finite(cond_h) && cond_h > COND_H_LIMIT) {
    warns <- c(warns, sprintf("the Hessian's condition number is %.3g (above %g): the model may be ill defined",
                              cond_h, COND_H_LIMIT))
  }
  if (length(re$singular)) {
    warns <- c(warns, paste0("near-singular random effects of ", paste(unlist(re$singular), collapse = ", "),
                             " (a standard deviation near 0 or a correlation near +-1): ",
                             "the data support a simpler random structure"))
  }
  out$formula <- last$formula
  out["error"] <- list(NULL)
  out$nobs <- num(nobs(m))
  out$groups <- if (mixed(m)) as.list(m$dims$nlev.gf) else setNames(list(), character())
  out$log_lik <- num(m$logLik)
  out$aic <- num(AIC(m))
  out$convergence <- c(optimiser(m), list(inner_iterations = as.character(info$niter),
                                          max_grad = num(max(abs(m$gradient))), cond_h = cond_h))
  out$thresholds <- coefficient_rows(co, seq_len(nalpha), FALSE)
  out$fixed <- coefficient_rows(co, nalpha + seq_len(nbeta), TRUE)
  out$random <- re$sd
  out$correlations <- re$correlations
  anova <- tryCatch(collecting(wald_anova(m), function(text) warns <<- c(warns, text)),
                    error = function(e) e)
  if (inherits(anova, "error")) {
    warns <- c(warns, paste("car::Anova failed:", conditionMessage(anova)))
    out$anova <- list()
  } else {
    out$anova <- lapply(rownames(anova), function(t) {
      list(term = t, chisq = num(anova[t, "Chisq"]), df = num(anova[t, "Df"]), p = num(anova[t, "Pr(>Chisq)"]))
    })
  }
  if (!is.null(job$term)) {
    terms <- tryCatch(suppressMessages(collecting(term_summaries(m, d, job$term, job$response, unlist(job$values)),
                                                  function(text) warns <<- c(warns, text))),
                      error = function(e) e)
    if (inherits(terms, "error")) {
      warns <- c(warns, paste("emmeans failed:", conditionMessage(terms)))
    } else {
      out <- c(out, terms)
    }
  }
  out$warnings <- as.list(unique(warns))
  out
}

# The data of the job being run, in the global environment: refits inside ordinal (nominal_test,
# scale_test) and emmeans look the data up from there.
.vispeech_data <- NULL

run_job <- function(job) {
  d <- read_job_data(job)
  .vispeech_data <<- d
  fit <- fit_first(unlist(job$formulas))
  out <- describe_fit(fit, job, d)
  if (!is.null(job$proportional_odds)) out$proportional_odds <- proportional_odds(job$proportional_odds)
  out
}

args <- commandArgs(trailingOnly = TRUE)
request <- jsonlite::fromJSON(args[1], simplifyVector = FALSE)
versions <- list(R = paste(R.version$major, R.version$minor, sep = "."))
for (p in needed) versions[[p]] <- as.character(packageVersion(p))
result <- list(versions = versions, jobs = lapply(request$jobs, run_job))
jsonlite::write_json(result, args[2], auto_unbox = TRUE, digits = NA, null = "null", na = "null")
