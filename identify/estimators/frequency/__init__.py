"""The frequency home: everything computed on finite Fourier transforms of flown runs.

``base`` the one finite Fourier transform (batch ``fit``, streaming ``partial_fit``); ``response``
the model-free frequency-response estimate (composite windows, coherence, random errors) and
Tischler's fit cost J of a model against it; ``bode`` its plots; ``equation_error`` Morelli &
Klein's frequency-domain equation error (``FDEE``, batch and streamed). A model's own response
is :meth:`identify.model.linear.LinearModel.frequency_response`.

Importing this package loads no submodule (scipy.signal, matplotlib stay out until used).
"""
