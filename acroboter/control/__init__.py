"""The controllers: the desired path, the three inverse-dynamics methods (MLM, Penalty, Iterative), input
recovery and the bounded input distribution. They see the model through the compiled bindings only."""
