"""The ground floor: what every package of factory stands on, importing nothing else of the project.

- :mod:`factory.core.errors`: the one error hierarchy (:class:`~factory.core.errors.FactoryError`);
- :mod:`factory.core.atomic`: output files that appear whole or not at all;
- :mod:`factory.core.yamlfile`: YAML input read with its file named in every error;
- :mod:`factory.core.resources`: where the data that ships with factory lives;
- :mod:`factory.core.progress`: progress reports from long work, without a terminal;
- :mod:`factory.core.units`: the millimetre-to-metre factor where the part crosses between domains.

The domain packages (:mod:`cadcam`, :mod:`robotprog`, :mod:`vision`) import only this floor;
the pipeline above them (the rest of :mod:`factory`) and the CLI import everything.
"""
