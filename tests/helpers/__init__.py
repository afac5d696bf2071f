"""What the tests share: one two-sample test and the binomial and family-wise rates
(:mod:`tests.helpers.stats`), the CLI runners (:mod:`tests.helpers.cli`) and fake time for
drivers (:mod:`tests.helpers.clock`)."""
