"""What is measured on a pile: base forces, contact networks, surfaces and
angles of repose (`analysis`), a heap's base-force profile and its dip
(`heap`), a poured heap's measurements (`poured_heap`), a cone of spheres'
(`cone_heap`), voidage (`voidage`),
a measured profile read at given points (`base_reading`), and the papers'
analytic models (`theory`). These modules are public; the rest of the
package is what they are built from."""

from jaxpile.measure import analysis, base_reading, cone_heap, heap, poured_heap, theory, voidage

__all__ = ["analysis", "base_reading", "cone_heap", "heap", "poured_heap", "theory", "voidage"]
