"""``python -m mantis_rig.contract [DOCUMENT]``: print the contract's generated section, or
rewrite it in DOCUMENT."""
import sys

from .interfaces_document import markdown, update_document

if len(sys.argv) > 1:
    changed = update_document(sys.argv[1])
    print(f'{sys.argv[1]}: {"updated" if changed else "up to date"}')
else:
    sys.stdout.write(markdown())
