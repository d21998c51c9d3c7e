"""The paper's numbers a run of its crane is compared with (the table's and the step-time figure's MATLAB column)."""

# Mean control-step time in MATLAB R2019b on an i7-8700 (paper, section 4), in microseconds.
PAPER_MATLAB_US = {"mlm": 309.06, "penalty": 304.78, "iterative-3": 384.28, "iterative-4": 385.41,
                   "iterative-5": 410.62}
