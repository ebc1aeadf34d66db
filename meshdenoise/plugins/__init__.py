"""Filter families, one module each. Importing this package registers every filter.

Every module in this folder is imported, so a new filter family is one new file.
"""

import importlib
import pkgutil

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")
