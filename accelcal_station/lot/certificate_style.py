"""The certificate's inline stylesheet: A4 pages that print one board each (no CDN, no fonts fetched)."""
from __future__ import annotations

CSS = """
@page { size: A4; margin: 11mm 13mm; }
* { box-sizing: border-box; }
html { background: #e8e8e8; }
body { margin: 0; font: 7.9pt/1.22 "DejaVu Sans", "Liberation Sans", Arial, sans-serif; color: #111; }
section.certificate { background: #fff; width: 210mm; min-height: 297mm; margin: 6mm auto; padding: 11mm 13mm;
  box-shadow: 0 0 3mm rgba(0,0,0,.25); break-after: page; page-break-after: always; }
section.certificate:last-of-type { break-after: auto; page-break-after: auto; }
@media print {
  html { background: none; }
  section.certificate { width: auto; min-height: 0; margin: 0; padding: 0; box-shadow: none; }
}
header { display: flex; justify-content: space-between; align-items: flex-start; border-bottom: 2pt solid #1d3557;
  padding-bottom: 2mm; margin-bottom: 1mm; }
h1 { font-size: 17pt; margin: 0; color: #1d3557; letter-spacing: .02em; }
.sub { margin: 1mm 0 0; color: #444; }
.id { text-align: right; }
.id p { margin: 0; }
.serial { font-size: 12pt; font-weight: bold; }
.verdict { display: inline-block; margin-top: 1mm !important; padding: .5mm 4mm; font-size: 13pt; font-weight: bold;
  border: 1.5pt solid; border-radius: 1mm; }
.verdict.pass { color: #0b6e2e; }
.verdict.fail { color: #a4161a; }
h2 { font-size: 9pt; margin: 2mm 0 .8mm; padding-bottom: .4mm; border-bottom: .8pt solid #1d3557; color: #1d3557;
  break-after: avoid; page-break-after: avoid; }
.two { display: flex; gap: 5mm; }
.two > div { flex: 1 1 0; min-width: 0; }
table { border-collapse: collapse; width: 100%; break-inside: avoid; page-break-inside: avoid; }
th, td { border: .5pt solid #b5b5b5; padding: .15mm 1.2mm; text-align: left; vertical-align: top; }
th { background: #f1f3f6; font-weight: 600; }
table.kv th { width: 42%; }
td.num, .num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
table.cal td, table.budget td { font-variant-numeric: tabular-nums; }
table.budget { font-size: 7.2pt; }
table.budget th { font-size: 7pt; }
tr.total td { font-weight: bold; background: #f7f7f7; }
td[data-field="config_sha256"], .hash { font-family: "DejaVu Sans Mono", monospace; font-size: 7pt;
  word-break: break-all; }
.note { margin: .8mm 0 0; font-size: 7.2pt; color: #444; }
footer { margin-top: 3mm; border-top: .8pt solid #1d3557; padding-top: 1.2mm; }
footer p { margin: 0; }
code { font-family: "DejaVu Sans Mono", monospace; }
"""
