"""The studies behind the README's figures: each a trial function for :mod:`pmht_opt.montecarlo` and a
``run`` that writes its results under a directory. ``pmht-opt study NAME`` and the scripts in the
repository's ``studies/`` call them."""
