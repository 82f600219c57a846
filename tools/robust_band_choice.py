"""How the default robust band was chosen (issue 44): a sweep of bands on the *choice* images only.

The held-out images of ``vrcorrect bench robust`` (stereo_motorcycle, page) are never used here.
For each band, on desktop and quest2 and each choice image (scikit-image's astronaut, coffee and
text, the project's text chart, and since 2026-12-02 ``words``, the tuning clips' page of dark words on
light paper at 14 px; 256 px; the bench's eye -2.00/-1.00 x 120), the correction is
designed as ``--pupil auto --robust on`` designs it (the pupil from the image's light, the pupil
bank's nearest entry) with ``fast``, and seen by the eyes the issue checks: pupils 2.5, 3, 4, 5.5 mm
and the sphere 0.5 D off either way at the light's pupil.  Printed per case: the least JOD gain over
no correction (the issue's bar: -0.05) and, at 3 mm, the share of the gain of a correction designed
for exactly 3 mm (the issue asks 80 %).

    .venv/bin/python tools/robust_band_choice.py                      # the default and the first band
    .venv/bin/python tools/robust_band_choice.py "pf=1;sp=1,3,1"      # any band: pf pupil factors, pp their
                                                                      # priors, so sphere offsets, sp priors
    .venv/bin/python tools/robust_band_choice.py off                  # no band: the one eye, no light cap
    .venv/bin/python tools/robust_band_choice.py --image scan.png ""  # the default on the choice images and
                                                                      # a picture of your own (repeatable;
                                                                      # centre-cropped and scaled to 256 px)
    .venv/bin/python tools/robust_band_choice.py --documents DIR --no-builtin off   # the real pages'
                                                                      # choice half (tools/fetch_documents.py)
    .venv/bin/python tools/robust_band_choice.py --solver twin:10 ""  # designed by the real-time twin
                                                                      # (10 frames of the still), not fast
    .venv/bin/python tools/robust_band_choice.py "pf=1.2;so=0,0.5;sp=3,1;pull=0.005+nocap"   # with a pull
                                                                      # towards the target (RobustBand.pull)

About a minute and a half for the first band on 2 cores (the seen eyes' kernels are built then), seconds
for each after it.  Dev machine, 2026-11-28, the worst case over the eight (least gain; share at 3 mm,
the chart aside, whose gains are under 0.1 JOD):

* the first band, pf=0.8,1,1.25 pp=1,2,1 so=-0.25,0,0.25 sp=1,2,1: -0.10; 54 % (scikit-image's text);
* pf=1 sp=1,3,1: -0.60; 71 %;  pf=0.964 sp=1,3,1: -0.32; 75 %;
* pf=0.928 (one bank step below the entry) sp=1,2,1: +0.03; 75 %;  the same with sp=1,4,1: -0.10; 81 %;
* pf=0.928 sp=1,3,1, the default: -0.03; 79 % (the chart on quest2: 74 %).

Tried later (second sweep, same images): sphere offsets +-0.5 D (sp=1,8,1) or five offsets
(sp=1,1,6,1,1): shares fall to 61-73 % on text; two pupils pf=0.928,1: -0.28; pf=0.9 sp=1,4,1: +0.02,
79 %; pf=0.9 sp=1,5,1: +0.05, 81 % (the chart on quest2: 70 %); pf=0.88 or below: shares under 77 %.
pf=0.9 sp=1,5,1 is the only band found that meets both bars on the choice images; its figures on the
held-out images were looked at once (desktop least +0.06, quest2 page 70 % at 3 mm, below the
default's 76 %), so it was not adopted: choosing between the two on those figures would tune on
the held-out images.  Neither band meets 80 % on quest2's page; the bar is open (issue 44).

With the light cap (``fast`` caps a robust design's box since 2026-11-29; the same images, the same
machine; the least over the eight, and the least share at 3 mm but the chart's): the default
+0.03, 82 %; sp=1,4,1 +0.02, 84 %; sp=1,5,1 -0.04, 86 %; sp=1,6,1 -0.09, 87 %; pf=1 sp=1,3,1 -0.45;
pf=1 sp=1,5,1 -0.56.  The cap lifts every least gain (the default's worst was -0.03) and costs 0-5
points of share at 3 mm; the band was not chosen again: the default still meets both bars here.

Third sweep (2026-12-02, the same machine), after the held-out pages stayed at 79 % / 75 %.  The
choice images had no bright page of text with gains of a tenth of a JOD or more (the chart's are
under 0.1), so ``words`` joined them; bands of a new family (the sphere hedged towards the sharper
eye only, ``so=0,0.25``, at the bank entry or near it) were swept too.  The least gain over all ten
cases, the least share at 3 mm but the chart's, and the share on ``words`` on quest2 (light 2.70 mm):

* the default (pf=0.928 sp=1,3,1): +0.03, 63 % (quest2 words; desktop words 76 %);
* pf=0.928 sp=1,4,1: +0.02, 63 %;  pf=0.964 so=0,0.25 sp=1.5,1 / 2,1 / 3,1: +0.02 / +0.03 / -0.04, 60 / 63 / 66 %;
* pf=1 so=0,0.25 sp=1,1 / 1.25,1 / 1.5,1 / 1.75,1: +0.03 / +0.03 / -0.03 / -0.10, 65 / 67 / 68 / 70 %
  (sp=2,1 and 3,1, on the eight cases before ``words``: -0.15 and -0.32);  pf=1 so=-0.25,0,0.25
  sp=1,3,3: +0.03, 65 % (desktop words; quest2 words 69 %);  pf=1.04 so=0,0.25 sp=1,2 / 1,1.5: +0.03 / -0.04, 69 / 71 %.

No band keeps 80 % on a bright page on quest2 and stays above none elsewhere (the sharper bands'
least gains are the desktop photographs with the sphere 0.5 D off: astronaut, coffee).  What costs
the pages is the robustness itself, not the pupil alone: a single-eye design for exactly the light's
pupil keeps 99 % (desktop, 2.91 mm) and 84 % (quest2, 2.70 mm) of the exact 3 mm gain on ``words``,
where the bands keep 65-77 % and 60-71 %; the sphere hedge (with the light cap) costs text most
(pf=1 so=0,0.25 sp=1,1 designs at the bank entry 2.90 mm on desktop and keeps 72 %, where a single
eye at 2.90 mm keeps 98 %).  Text needs the
modelled sphere nearly alone; the photographs need the hedge to stay above none at +0.5 D.  The best
band by the rule "the greatest least share with every least gain at or above 0" is pf=1.04 so=0,0.25
sp=1,2 (69 %, +0.03): six points over the default on quest2's ``words`` (four under it on desktop's)
and still eleven short of the bar.  Not adopted: it widens the real-time grids (a design pupil above
the entry) and changes every figure measured with the default band, for a gain that leaves the bar
unmet.  A band that suits both would have to depend on the picture (text against photographs), which
the real-time path's designs, shared by every frame, do not.

Fourth look (2026-12-02): a design that depends on the picture, tried and not adopted (commit 80556c2
holds its code and figures; reverted in the next).  The physics objective is no judge of when a band
may be sharp: with the sphere 0.5 D off, the one eye's design (with the light cap) on desktop
``coffee`` still lowers the objective by 6 % where ColorVideoVDP sees it 0.62 JOD below none.  So
the picture was judged instead: a page of dark text on light paper (mostly paper and ink, few
mid-tones, a smooth paper light) was designed for the one eye at the bank entry without the band and
the light cap.  On the choice pages that kept 98 % / 83 % (``words``, desktop / quest2; least +0.04 /
-0.01) and 98 % / 87 % (the chart; -0.02 / +0.02) of the exact 3 mm gain; with the cap 79 % on desktop
``words``.  On the held-out scanned page (``vrcorrect bench robust``) it kept 100 % / 97 % at 3 mm but
fell 0.90 / 0.22 JOD below none with the sphere 0.5 D off (2.7x / 1.3x none's objective), where the
default stays at +0.09 / +0.05; the clean rendered pages of the choice set showed no such fall (why
the scan does is a guess, below).  (The first page
rule, one paper level for the picture, judged that scan no page; its shading model was added after
that verdict, so the scan's figures were not blind to that step.)  What this leaves: the choice set
needs real documents (scans or photographs of pages, none of them the held-out scan; ``--image``
adds them) before any picture-dependent design can be chosen; until then the default band stays, and
the pages' 80 % bar (79 % / 75 % on the held-out page) stays open.

Real documents, looked at the same day (``--image``; ``off`` is the one eye at the bank entry without
the cap).  OCRmyPDF's test scans (``pip download --no-deps --no-binary :all: ocrmypdf==16.0.0``,
``tests/resources``, CC-BY-SA / public domain from Wikimedia): ``linn.png`` cropped to
(150, 1250)-(1000, 2100) (a printed manual, two columns, about 12 px text at 256 px),
``typewriter.png`` to (400, 700)-(2400, 2700) (a typed page) and ``baiona.png`` whole (a map with
labels).  Share at 3 mm and least gain, desktop / quest2:

* the default band: linn 76 % +0.13 / 72 % +0.14; typewriter 74 % +0.10 / 71 % +0.05; baiona 90 %
  +0.09 / 84 % +0.05 (the pages fall short of 80 % as the held-out scan does);
* ``off``: linn 96 % -0.04 / 80 % +0.08; typewriter 98 % -0.01 / 86 % +0.05; baiona 99 % +0.02 /
  95 % +0.05: both bars met on all three, where the held-out scan fell to -0.90 / -0.22.

So the one-eye design is safe on some real pages and not on others.  A guess, not tested: the
held-out scan's paper is grey and grainy (scikit-image's ``page``: a small scan, enlarged here), where
white paper sits at the top of the box [0, 1] and a correction cannot lift its grain; a page rule that
asks for white paper would then separate them.  Choosing that would lean on the held-out scan; it
needs more real pages (grey paper, photographed pages, e-readers) chosen on and others held out.

Fifth look, planned before its figures (2026-12-02): ten real pages (``tools/fetch_documents.py``),
split before any correction was made of the new ones into a choice half (linn, typewriter, baiona,
c02-22: a book page on tinted paper, its paper at 0.71 of white; epson, francais) and a held-out half
(sudoku: a photographed newspaper page; imageTextN, masks, kcs).  The reverted page rule (80556c2)
calls all six choice pages pages.  Candidate designs for a page: ``off`` (the one eye, no cap, as
80556c2), ``off+cap`` (the one eye under the light cap), and ``off`` only where the paper is white (its
fitted light at least 0.9 of white; the default band elsewhere).  The rule kept is the simplest that
meets both bars (least gain -0.05 or above, 80 % at 3 mm) on every choice page on both displays; it is
then judged once on the held-out half and on ``vrcorrect bench robust``'s page.  If none meets them,
nothing changes.

What the choice half gave (least gain at the sphere 0.5 D off or a pupil, share at 3 mm; desktop /
quest2; dev machine, 2-core, 2026-12-02):

* the default band: least +0.04 to +0.18, but shares 53-90 % (c02-22 66 / 53 %, francais 68 / 60 %):
  the bar missed on five of six pages on each display;
* ``off``: c02-22 -0.43 on desktop (the sphere +0.5 D; tinted paper, as the held-out scan fell),
  francais 78 % on quest2; ``off+cap``: c02-22 -0.37, shares 74-94 %.  None of the three planned
  candidates meets both bars (the white-paper rule leaves c02-22 at the default's 66 / 53 %).

Then, still on the choice half only, bands of the third sweep's family without the light cap (the cap
costs thin strokes most: francais desktop 98 % with ``off``, 75 % with ``off+cap``): pf=1.04 so=0,0.25
without the cap, with sp=3,1 / 4,1 / 5,1 / 6,1: c02-22 desktop -0.05 / -0.14 / -0.21 / -0.25, quest2
francais 77 / 79 / 80 / 81 %; every white page meets both bars from sp=5,1 (least -0.02, shares 80-98 %);
with the cap (sp=3,1) shares fall to 68-92 %; pf=1 (at the entry) keeps less on quest2 (65-91 %),
pf=1.08 falls to -0.07 on white pages.  No single band meets both bars on all six pages: the tinted
page wants the hedge, the thin sans-serif on quest2 the sharpness.

So the rule judged next (``page-rule``, planned here before the held-out half is looked at): a page
(:func:`vrcorrect.physics.page.page_verdict`) on white paper (its fitted light at least 0.9 of white)
is designed over pf=1.04 so=0,0.25 sp=5,1 without the cap; a page on darker paper over the same with
sp=3,1; anything else over the default band with its cap.  It is chosen on six pages, one of them
tinted, so it may not hold: it passes if, on every held-out page on both displays, the least gain is
-0.05 or above and the share at 3 mm 80 % or more.

On the whole choice set (the built-in images too) the rule met both bars: least -0.048 (c02-22,
desktop), shares 80-98 % on the pages (the photographs, judged no page, keep the default's figures).

Judged once, the same day: it fails.  On the held-out half (``--documents DIR --held-out page-rule
""``) the white pages gain (imageTextN 92 / 85 % at 3 mm, the default 78 / 68 %; masks 94 / 82 %, the
default 73 / 69 %; least +0.03 to +0.04), kcs (two large handwritten words, gains of 0.02-0.04 JOD)
keeps 101 / 70 % (the default 101 / 99 %), and the photographed sudoku, judged no page (its paper
light 0.22), keeps the default's 79 / 81 % (least -0.01 / +0.07).  On ``vrcorrect bench robust``'s
held-out scanned page, judged a page on grey paper (0.58), the grey branch falls 0.47 JOD below none
on desktop with the sphere 0.5 D off (-0.05 on quest2), where the default stays at +0.09 / +0.05: the
one tinted choice page (c02-22, at -0.048) did not stand for grey paper.  Not adopted.

What it leaves for a next look: on white paper the sharper band without the cap held on every page
seen (least -0.023 or above on 10 white pages, choice and held-out, both displays; shares 80-101 %
but kcs's 70 % on quest2), where the default keeps 60-90 % on the real white pages; grey and tinted paper
fell below none with every design sharper than the default that was tried (``off``: -0.43 on c02-22;
the grey branch: -0.47 on the held-out scan).  A rule "white page: the sharper band; anything else:
the default" is supported by these figures but was not planned before them, and leaves the issue's
held-out scan (grey) at the default's 79 / 75 %; the real-time path would need it too (a page
design per bank entry, and a design pupil above the entry, which widens the grids).
Sixth look (2026-12-02, later; the choice pages only, nothing held out looked at): why grey paper
falls.  ``--grey-paper 0.58`` adds grey stand-ins of the white choice pages (``linn@0.58`` and so on:
each page's light times 0.58, the held-out scan's paper), and a band's text may end in ``+paper[=F]``:
each primary capped at F times the brightest target light within ``PAPER_REACH_PX`` (6 px at 256 px),
the page's paper near a stroke; at F=1 a page cannot be lit above its paper, as white paper cannot be
by the display.  ``--documents /tmp/realdocs --no-builtin --grey-paper 0.58 "" B+nocap B+paper
B+paper=1.3 off+paper`` with B = pf=1.04;so=0,0.25;sp=5,1 (dev machine, 2026-12-02; least gain, share
at 3 mm; the six choice pages, then the four stand-ins):

* the default: +0.04 to +0.18, 53-90 %; stand-ins +0.04 to +0.23, 73-83 % (desktop) / 67-79 % (quest2);
* B without the cap: stand-ins -0.40 to -0.71 on desktop and -0.13 to -0.47 on quest2 (the sphere
  +0.5 D), at 96-99 %: they fall as the held-out scan did (-0.47), where c02-22 (tinted) fell less
  (-0.21), so the stand-ins stand for grey paper better than c02-22 did;
* B under the paper cap: the white pages nearly as without it (-0.023 to +0.09, 80-96 %); stand-ins
  -0.069 to +0.12 but 28-42 %, c02-22 51-54 %;  B+paper=1.3: stand-ins -0.31 to +0.10, 67-75 %;
  the one eye under the paper cap: as B+paper, stand-ins 27-42 %.

On grey paper the share at 3 mm and the fall with the sphere off have one source, light added above
the paper: removing it removes both.  No design tried on grey paper keeps 80 % at 3 mm and stays
above none; the default (73-83 %, 67-79 %) is the best of them there.  Nothing adopted.

Seventh look, planned before its figures (2026-12-02, later): the rule the fifth look's figures
supported, ``white-rule``: a page (:func:`vrcorrect.physics.page.page_verdict`) on white paper (its
fitted light at least 0.9 of white) is designed over pf=1.04 so=0,0.25 sp=5,1 without the light cap
(the page rule's white branch); anything else over the default band with its cap.  The ten real
pages are spent on this rule family, so it is judged on fresh pages, made after this was written:
``tools/render_pages.py`` draws six pages of rendered text as a monitor or a headset shows it
(serif 12 px, sans 11 px in dark grey, a Times-like 14 px, mono 12 px on off-white, Computer Modern
18 px, sans 14 px with blue links; 256 px).  It passes if, on every fresh page and both displays,
the least gain is -0.05 or above and the share at 3 mm 80 % or more, and if every fresh page is
judged a page on white paper.  The default is run beside it, for the comparison only.  Whatever the
figures, the rule leaves grey paper (the issue's held-out scan) at the default's 79 / 75 %, and the
real-time path would need a page design per bank entry: a pass supports building it, and closes
nothing.

Judged once, the same day (``render_pages.py /tmp/fresh``, then ``--no-builtin --image`` each page,
``"" white-rule``; dev machine, 2 cores): it passes.  Every fresh page was judged a page on white
paper (paper light 0.96-1.00).  Least gain and share at 3 mm, desktop / quest2:

* white-rule: least +0.003 to +0.067 / +0.014 to +0.086; shares 93-95 % / 81-93 % (the lowest: sans
  11 px 81 %, links 82 % on quest2);
* the default beside it: least +0.04 to +0.14 / +0.02 to +0.10, but shares 47-71 % / 54-77 %: on
  rendered text, what a monitor or a headset shows, the default keeps even less than on scans.

So on white pages the sharper band without the cap meets both bars on 16 pages (eight real
scans, the two built-in rendered pages, six fresh ones; kcs's 70 % on quest2 aside, whose whole gain is 0.03 JOD), where the default keeps 47-90 %.
Not yet in the product: neither ``fast`` nor the real-time path chooses a band by the picture, and
the issue's held-out scan is grey.  (Both choose it since 2026-12-02 / 12-03.)

Eighth look (2026-12-03): the page band chosen again for the real-time path.  Judged on the six
fresh pages, the real-time default (the CPU twin after 10 frames, ``--solver twin:10``) fell to -0.06
/ -0.07 with the sphere +0.5 D on two desktop pages and kept 71-84 % at 3 mm on quest2, where
``fast`` with the same band had held: the twin reaches the band's optimum (its objective lower than
``fast``'s, which stops at its tolerance), and the optimum of the seventh look's band is sharper
than a page's eyes allow.  So the band was chosen again on the choice pages' white half (linn,
typewriter, epson, francais, baiona and the two built-in pages, ``words`` and ``chart``, as 256 px
PNGs; ``--no-builtin --image``), by the twin.  Least gain and the least share at 3 mm over the 14
cases (desktop and quest2); the twin after 150 frames, run on 13 of the cases (two bands), gave the
same least gains within 0.005 JOD and the same shares within a point:

* the seventh look's band, pf=1.04 so=0,0.25 sp=5,1 (no cap, all below): -0.096 (francais, desktop,
  the sphere +0.5 D), 71 % (chart, quest2; francais 74 %);  sp=3,1: -0.060, 69 %;  sp=2,1: -0.028,
  67 %: a stronger hedge towards the sharper eye holds the floor and loses the share on quest2, whose
  light gives 2.65 mm (3 mm is 1.13 times it) where desktop's gives 2.86 mm;
* a larger design pupil: pf=1.1 sp=3,1 / 2,1: -0.148 / -0.116, 78 / 76 %; pf=1.15 sp=2,1: -0.178, 81 %;
  pf=1.04,1.2 pp=2,1 sp=3,1 / 1.5,1: -0.111 / -0.057, 77 / 73 %: the share comes back, the floor goes;
* the hedge to +0.5 D with it: pf=1.1 so=0,0.5 sp=3,1: +0.011, 72 %; pf=1.1 so=0,0.25,0.5 sp=4,2,1:
  +0.010, 71 %; pf=1.04,1.2 so=0,0.25,0.5 sp=4,2,1: +0.011, 73 %; pf=1.15 so=0,0.5 sp=4,1: -0.018,
  81 %; **pf=1.2 so=0,0.5 sp=3,1: -0.023, 83 %**; pf=1.2 so=0,0.5 sp=4,1: -0.065, 85 %; pf=1.3 so=0,0.5
  sp=3,1: -0.172, 86 %.

The rule, as before: the greatest least share with every least gain at -0.05 or above; pf=1.2
so=0,0.5 sp=3,1 (``white-rule-2``).  The same band with ``fast`` on the same pages: least -0.004,
shares 89-103 % (the seventh look's band with ``fast``: 80-98 %), so one band serves both.  It
became :data:`vrcorrect.physics.page.PAGE_BAND` before it was judged.  Planned before its figures:
it is judged once on six fresh pages made after the choice (``tools/render_pages.py --set 2``: other
fonts, sizes, inks and prose; every one judged a page on white paper), by ``vrcorrect bench robust
--no-write --image`` each page; it passes if the default (``fast``) and the real time keep every
least gain at -0.05 or above and 80 % at 3 mm on every page and both displays.

Judged once, the same day (dev machine, 2 cores, 6 min): every page was judged a page on white paper
(paper light 0.92-1.00).  ``fast`` passes on every page: least gain +0.02 to +0.17 (desktop) and
+0.03 to +0.13 (quest2), shares at 3 mm 86-99 %.  The real time passes on five pages of six
(least -0.01 to +0.16, shares 82-95 %) and fails on ``grey16`` (sans 16 px in grey ink, 70/255, with
blue links): least -0.05 on desktop and -0.07 on quest2 (the sphere +0.5 D), 82 % and 72 % at 3 mm.
So the rule fails the bar as planned, on one low-contrast page, in real time only.  It stays the
product's page band (decided before the comparison below was run): it was chosen on the choice
pages, where it is the only band tried that meets both bars in real time, and ``fast`` with it
passes.  For the record only, the seventh look's band on the same six fresh pages by the twin:
see docs/realtime.md.

Ninth look (2026-12-03, later): why the real time lost where ``fast`` held, and a pull towards the
target.  First a guess, tried on the choice pages only: grey ink.  ``--grey-ink 0.06 --grey-ink 0.15``
adds stand-ins of the white choice pages with the ink lifted to 0.06 and 0.15 of white (the paper
kept); by the twin with the eighth look's band they keep the white pages' figures (least -0.026 to
+0.124, shares 82-96 %), so grey ink alone is not what failed.  Then the failed page itself, looked at
once for the cause (not for a choice): on ``grey16`` (desktop) and on the choice page ``francais``
the twin's view is 0.04-0.05 JOD below ``fast``'s at every eye, the design's own too (``grey16`` at
3 mm +0.24 against +0.29), while its objective on the design's problem is lower (0.01687 against
0.01720; francais 0.01352 against 0.01386), and it stays there (40 and 150 frames give the same).  On
francais frame by frame, the gain with the sphere +0.5 D is +0.12, +0.09, +0.03, +0.02, -0.00 after 1,
2, 3, 4 and 6 frames, the other eyes nearly unchanged.  What the iterations add after ``fast``'s early
stop (4 iterations there) lies at 32-128 cycles an image (256 px), where the band's summed transfer is
weak, and drives pixels to the box's ends (at 0: 4 % of pixels in ``fast``'s view, 11 % in the twin's).
The eye 0.5 D off sees that fine detail in the wrong phase.

So the band gains a pull towards the target (``RobustBand.pull``, ``pull=`` in a band's text): ``pull
||A||^2 ||x - t||^2`` in the expectation, in the effective kernel itself (the floor of
:func:`vrcorrect.physics.robust.effective_kernels`), so ``fast``, the twin and the GPU share it at no
cost.  Tried first on four choice pages by the twin (pulls 0.003, 0.01, 0.03 on the eighth look's band):
the least gain rises (francais desktop -0.01 to +0.01 / +0.08 / +0.09) and the share falls (83 to 83 /
76 / 60 %).  The rule, written then, before the sweep below: the greatest least share at 3 mm with every
least gain at 0 or above (a margin of 0.05 over the bar: the eighth look's fresh pages fell up to 0.05
below its choice pages' least).  The sweep by the twin on the seven white choice pages, both displays
(14 cases; least gain; least share at 3 mm), all without the light cap:

* the eighth look's band (pf=1.2 so=0,0.5 sp=3,1, no pull): -0.023, 83 %;
* with pull=0.003 / 0.004 / 0.005 / 0.007: -0.003 / +0.002 / **+0.005** / +0.013, 83 / 82 / **82** / 80 %;
* sp=4,1 pull=0.005: -0.023, 85 %;  sp=3.5,1 pull=0.006: -0.003, 83 %;  so=0,0.25,0.5 sp=4,1,1 pull=0.005:
  -0.025, 84 %;  sp=5,1 pull=0.01: -0.015, 82 %;
* pf=1.25 sp=3,1 pull=0.005: -0.054, 85 %;  pf=1.25 sp=4,1 pull=0.01: -0.042, 82 %;  pf=1.3 sp=3,1
  pull=0.01: -0.075, 80 %;  pf=1.15 sp=3,1 pull=0.005: +0.013, 77 %.

By the rule: pf=1.2 so=0,0.5 sp=3,1 pull=0.005 (``white-rule-3``; pull=0.004 ties at 82 % with a lower
least gain).  The least share is desktop francais's in every band; desktop's shares 82-98 %, quest2's
84-94 %.  With ``fast`` on the same pages: least +0.008, shares 81-99 % (without the pull -0.004,
89-103 %).  It became :data:`vrcorrect.physics.page.PAGE_BAND` before it was judged.  Planned before
its figures: it is judged once on six fresh pages written before the choice (``tools/render_pages.py
--set 3``: bold serif 14 px, grey oblique sans 12 px, Computer Modern italic 16 px, dark blue bold mono
11 px, sepia bold STIX 13 px on cream, grey sans 20 px with red links), by ``vrcorrect bench robust
--no-write --image`` each page; it passes if ``fast`` and the real time keep every least gain at -0.05
or above and 80 % at 3 mm on every page and both displays.

Judged once, the same day (dev machine, 2 cores, 6 min): it passes.  Every page was judged a page on
white paper (paper light 0.91-1.00).  ``fast``: least gain +0.03 to +0.14 (desktop) and +0.01 to +0.06
(quest2), shares at 3 mm 84-101 % and 87-96 %.  The real time (the twin after 10 frames): least +0.01
to +0.13 and +0.00 to +0.07, shares 81-103 % and 86-91 %.  The least gains lie with the sphere +0.5 D
on desktop (five pages of six; cmti16's at the 5.5 mm pupil) and at the 5.5 mm pupil on quest2 (four
of six; the real time's oblique12 and serifb14 with the sphere +0.5 D); the lowest of all, serifb14's
+0.00 to +0.03, is with the sphere +0.5 D but ``fast``'s on quest2 (+0.01, at 5.5 mm).  With the
sphere +0.5 D the objective still puts ``fast``'s view at 1.10-1.29 times none's error,
and FLIP above none, where JOD puts it at or above none: the price of designing for the sharper side,
smaller than the eighth look's (1.07-1.38) but not gone.

Does the pull rescue grey paper?  Looked at the same day, the choice half only (``--documents
/tmp/realdocs --no-builtin --grey-paper 0.58 --solver twin:10``: c02-22 and the four grey stand-ins,
both displays; least gain, shares at 3 mm desktop / quest2).  No:

* the default band: +0.04, 65-81 % / 53-78 %;
* the page band as it is (pull 0.005, no cap): -0.42 (quest2 francais@0.58, the sphere +0.5 D), 65-80 %
  / 82-88 %; under the light cap: -0.30, 59-72 % / 77-84 %; pull 0.03 under the cap: +0.03, 36-51 % /
  54-65 %;
* the default band with pull 0.005: +0.03, 60-75 % / 52-73 %.

On grey paper the pull trades share for floor as it does on white paper, but the fall it must stop
with the sphere +0.5 D is four to eight times deeper; no band tried keeps 80 % there and stays above
none, so grey paper keeps the default band and the held-out scan its 79 % / 75 %.

Tenth look (2026-12-03, a fourth session that day): the default band's shape made sharper for grey
paper, under its light cap.  ``tools/render_pages.py --set 4`` (six pages on grey paper, 0.40-0.80 of
white) was written before the sweep's second half was read, to judge a band if one passed; none did,
so it is not spent.  The choice half of grey paper (``--documents /tmp/realdocs --no-builtin
--grey-paper 0.58 --solver twin:10``: c02-22 and the four stand-ins, both displays; least gain, and
shares at 3 mm desktop / quest2, over those ten cases):

* the default (pf 0.93, so -0.25/0/+0.25, sp 1,3,1): +0.04, 65-81 % / 53-78 %;
* the design pupil raised, pf 1.0 / 1.07 / 1.15 (default spheres): -0.26 / -0.65 / -1.12, 80-89 / 86-90
  / 76-91 % on desktop, 73-93 / 87-101 / 89-94 % on quest2; the modelled sphere counting six times
  (pf 1.0): -0.44, 84-93 % / 76-95 %;
* a fourth sphere member, +0.5 D, towards the sharper eye (so -0.25/0/+0.25/+0.5): with pf 1.07 and it
  counting 1 (sp 1,3,1,1): +0.03, 65-77 % / 69-87 %; counting 0.5 (sp 1,3,1,0.5): -0.19 (quest2
  francais@0.58, the sphere +0.5 D), 75-84 % / 77-94 %; with sp 1,4,1,0.5: -0.30, 78-85 % / 80-95 %;
  with pf 1.0 and sp 1,3,1,0.5: +0.04, 64-78 % / 62-83 %; with pf 1.15 and sp 1,3,1,1: -0.49, 73-81 %
  / 82-93 %.

The floor falls off a cliff as the share rises: between the two weights of the +0.5 D member the least
gain goes from +0.03 to -0.19 while the desktop shares rise by 7-10 points, and no band keeps both
80 % and the floor on the grey half (c02-22, tinted, keeps 53-93 % as the bands go).  Grey paper keeps
the default band, and the held-out scan its 79 % / 75 %.

Eleventh look (2026-12-03, a fifth session): other eyes (``--rx``).  The default band was chosen for the
bench's eye, whose blur is mostly its cylinder.  On the built-in choice images (``fast``), six eyes of
sphere alone and no accommodation (``accommodation_D`` 0, as a presbyope; their residual defocus at the
monitor / in the Quest 2 in brackets), least gain over the checked eyes, desktop / quest2:

* the bench's -2.00/-1.00 x 120 (-0.83 / -1.73 D): +0.04 / +0.03; +3.00/-1.00 x 90 (+4.17 / +3.27):
  -0.04 / -0.07;
* -0.25 (+1.42 / +0.52): -0.50 / -0.23;  -0.50 (+1.17 / +0.27): -0.97 / -0.10;  -1.00 (+0.67 / -0.23):
  -0.59 / -0.03;  -1.25 (+0.42 / -0.48): -0.21 / -0.31;  -1.50 (+0.17 / -0.73): -0.04 / -0.76;
  -2.00 (-0.33 / -1.23): -0.08 / -0.25.

Every eye of sphere alone falls below none on one display or both, each time with the sphere 0.5 D
towards focus: an eye sharper than the design, which over-sharpens for it.  Defocus alone changes its
blur with the sphere far more than the bench eye's astigmatism does.  Planned before the candidates'
figures were read: the default plus a fourth member 0.5 D towards the sharper eye (``sharper=1``,
stopped at focus, :func:`~vrcorrect.physics.robust.oriented_band`) counting 0.5, 1 or 2, run for the
bench eye, -1.00, -0.50, -2.00 and the hyperope; a band passes the choice if the bench eye keeps its
floor and its shares at 3 mm within 3 points of the default's, and only then is it judged on the
held-out images.  Least gain (shares at 3 mm, the chart aside), desktop / quest2:

* the bench eye: default +0.04 (76-91 %) / +0.03 (63-97 %); 0.5: +0.03 (68-83 %) / +0.03 (54-91 %);
  1: +0.03 (61-77 %) / +0.02 (49-86 %); 2: +0.02 (54-69 %) / +0.02 (43-79 %);
* -1.00: 0.5: -0.24 / -0.04; 1: -0.12 / -0.05; 2: -0.07 / -0.06 (shares at most 46 %);
* -0.50: 0.5, 1, 2: +0.04 to +0.06 / -0.06;  -2.00: -0.06 to -0.04 / -0.02 to +0.02;
* the hyperope: unchanged (-0.04 / -0.06 to -0.07).
* -1.50, run after the plan for the headset's case: default -0.04 / -0.76; 1: -0.03 / -0.03 (shares at
  3 mm 15-46 %); 2: -0.04 / -0.06 (10-66 %).

None passes: the bench eye's shares fall 8 to 22 points, and even at 2 the -1.00 D eye stays below
none on desktop.  The held-out images were not spent.  The issue's two bars (80 % at 3 mm, never
below none with the sphere 0.5 D off) pull apart for eyes of sphere alone: the design must give up
most of its gain at the eye as prescribed to spare an eye 0.5 D nearer focus.  Which to give up is a
product decision, not a band choice.

A guard instead of a band, looked at the same session (``--guard RHO``, the default band, ``fast``): the
correction blended towards the target, ``t + b (x - t)``, with the largest ``b <= 1`` that keeps the
objective of the eyes with the sphere 0.5 D off either way (at the light's pupil) at most RHO times
none's.  It acts per picture and per eye, and only where the objective sees harm.  RHO 1.25 was read
off held-out tables (``bench robust``: the bench eye's checked rows reach 1.20 by the objective where
JOD still gains; the falls of the -0.50 D and the -1.50 D eye sit at 1.5 to 82), so the held-out
images can no longer judge it.  Least gain on the choice images, desktop / quest2, default -> guarded:

* the bench eye: +0.04 / +0.03, unchanged (blend 1 on nine of ten; sktext on desktop 0.85, its share
  at 3 mm 82 -> 73 %);
* the hyperope: unchanged, blend 1 everywhere (its -0.04 / -0.07 are at the 4 mm pupil, not watched);
* -0.25: -0.50 / -0.23 -> -0.07 / -0.02;  -1.00: -0.59 / -0.03 -> -0.04 / -0.01;  -1.25: -0.21 /
  -0.31 -> -0.03 / +0.00;  -1.50: -0.04 / -0.76 -> -0.04 / -0.03;
* missed: -0.50 on desktop -0.97 -> -0.18 (coffee: blend 1, the objective sees no harm there), and
  -2.00 in the Quest 2 -0.25, unchanged (coffee, blend 1).

The guarded eyes keep little: 1-49 % of the exact gain at 3 mm.  So the objective sees the near-focus
over-sharpening (the eye 0.2 D from focus), not every fall: the -0.50 D eye on desktop, 0.67 D from
focus when 0.5 D nearer, falls by JOD where its objective barely moves.  Not in the product.

Twelfth look (2026-12-04): the guard is in the product as ``vrcorrect correct --guard RHO`` (default
off; this script's ``--guard`` calls it, and now prints the unguarded least and share beside the
guarded).  Judged once, as planned before the run, on four fresh photographs never used by issue 44
(scikit-image's chelsea, rocket, hubble_deep_field and immunohistochemistry, ``--no-builtin --image``),
``fast``, the default band, RHO 1.25, the bench eye and four eyes of sphere alone (-0.50, -1.00, -1.50,
-2.00 D, age 40, no accommodation).  The plan: adopt it as ``correct``'s default if (a) of the (eye,
display) cases below -0.05 unguarded, at least 3 of 4 end at -0.05 or above; (b) no case's least gain
falls by more than 0.02; (c) the bench eye's share at 3 mm falls at most 10 points.  Least gain over
the four photographs, unguarded -> guarded:

=========  ===================  ===================
eye        desktop              quest2
=========  ===================  ===================
bench      -0.45 -> -0.45       -0.61 -> -0.61
-0.50      -0.90 -> -0.90       -0.39 -> -0.17
-1.00      -1.32 -> -0.30       -0.01 -> +0.00
-1.50      -0.52 -> -0.52       -0.54 -> -0.08
-2.00      -0.06 -> +0.01       -0.41 -> -0.36
=========  ===================  ===================

(a) fails: one of nine failing cases is lifted; (b) holds for the (eye, display) cases, though picture
by picture a safe one loses up to 0.08 (-2.00 D on desktop, immunohistochemistry +0.11 -> +0.03); (c)
holds (the bench eye: blend 1 everywhere).  Not adopted.  Picture by picture it does what it was built for: of 21 (eye, display,
picture) cases of sphere alone below -0.05, it lifts 10 to -0.05 or above (-0.78 -> -0.02, -0.63 ->
+0.06, -0.87 -> +0.03, -0.41 -> +0.13), keeping 14-87 % of the exact gain at 3 mm.  What it leaves:
the dark photograph (hubble, light 4.1-4.8 mm), whose falls are at the 2.5 and 3 mm pupils or the
sphere 0.5 D off where the objective sees no harm (the bench eye there sees 0.96-1.00 x none's
objective at 2.5 mm while JOD falls 0.45-0.61), and rocket on desktop (-0.38 for the -0.50 D eye, blend
1).  The default band itself fails the bench eye on two of the four fresh photographs (rocket -0.15 /
-0.18 at 2.5 mm, hubble -0.45 / -0.61), where the choice and held-out images had kept it above
-0.05: the objective is linear in light and blind to errors on a dark ground.

Thirteenth look (2026-12-04): the lightness guard, ``vrcorrect correct --guard 1 --guard-measure
lightness`` (here ``--guard 1 --guard-measure lightness --guard-pupils``: the six eyes judged are the
guard eyes), judged once on four more pictures unused by issue 44 (scikit-image's retina, camera, coins,
moon; ``--no-builtin --image``), the same eyes, the same rule (and the guard made the default only if
every eye also keeps 50 % at 3 mm).  Least gain, unguarded -> guarded (desktop; quest2): bench -0.24 ->
-0.07; +0.00 -> +0.00.  -0.50: -0.64 -> -0.35; -0.08 -> -0.00.  -1.00: -0.81 -> +0.03; -0.02 -> +0.00.
-1.50: -0.05 -> -0.00; -0.29 -> +0.01.  -2.00: -0.12 -> +0.00; -0.20 -> -0.03.  (a) holds (six of eight
lifted), (b) holds, (c) fails: the bench eye on retina in the Quest 2 keeps 29 % at 3 mm where it kept
87 %.  An option, not the default; eyes of sphere alone keep 0-34 % at 3 mm on desktop.

Fourteenth look (2026-12-04): the visibility guard, ``--guard 1 --guard-measure visibility --guard-pupils``
against the same with ``lightness``, on four more fresh pictures (matplotlib's grace_hopper; scikit-image's
cell, gravel, brick: ``--no-builtin --image``), the same five eyes (``--rx`` for the four of sphere alone,
age 40).  Rule written before the runs: keep it as an option if it lifts at least as many (eye, display)
cases below -0.05 as lightness and keeps the bench eye's least 3 mm share at least as high on each display.
Each lifts six of eight; the bench eye's least share is 13 / 0 % (desktop, visibility / lightness) and
0 / 0 % (quest2: the 5.5 mm eye binds on gravel and brick).  Kept as an option; the guard stays off.  The
-1.00 D eye on desktop falls 1.51 JOD below none on brick without a guard.  Details: docs/realtime.md.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from vrcorrect.physics.page import WHITE_PAPER
from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.pupil import pupil_from_light
from vrcorrect.physics.robust import RobustBand, design_eye
from vrcorrect.plumbing.errors import VrcorrectError
from vrcorrect.plumbing.charts import text_chart
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.runtime.pupil_bank import nearest_bank_pupil
from vrcorrect.solvers import make_problem, solve
from vrcorrect.solvers.guard import GUARD_MEASURES
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.studies.bench.robust import EYE, IMAGES as HELD_OUT, held_out_image, realtime_still
from vrcorrect.vision.metrics import evaluate_seen

CHOICE_IMAGES = ("astronaut", "coffee", "sktext", "chart", "words")
DISPLAYS = ("desktop", "quest2")
SEEN = ((2.5, 0.0), (3.0, 0.0), (4.0, 0.0), (5.5, 0.0), (None, -0.5), (None, 0.5))   # None: the light's pupil
BANDS = ("pf=0.8,1,1.25;pp=1,2,1;so=-0.25,0,0.25;sp=1,2,1", "")                      # "": the default
_kernels: dict = {}
_cases: dict = {}
_exact_shown: dict = {}                                                          # (display, picture) -> fast's image
_files: dict[str, str] = {}                                                      # --image: name -> path
_eye = {"eye": EYE, "age": None}                                                 # --rx: the right eye, its age


#: The real choice pages on white paper, whose grey stand-ins ``--grey-paper`` adds (sixth look).
WHITE_CHOICE_PAGES = ("linn", "typewriter", "epson", "francais")


def choice_image(name: str) -> np.ndarray:
    assert name not in HELD_OUT
    for mark, lift in (("^", lambda v, x: v + (1.0 - v) * x),   # NAME^INK: grey ink, the ink lifted to INK of white
                       ("@", lambda v, x: v * x)):                # NAME@LIGHT: grey paper, the page's light times LIGHT
        if mark in name:
            from vrcorrect.specs.display import encode

            page, value = name.split(mark)
            linear = decode("srgb", choice_image(page)).astype(np.float64)
            return encode("srgb", lift(float(value), linear)).astype(np.float32)
    if name in _files:                   # a picture given with --image (a real document, say)
        from vrcorrect.plumbing.imageio import read_image

        return prepare_image(read_image(_files[name], []), 256, name)
    if name == "chart":
        return prepare_image(text_chart(256, 256), 256, "chart")
    if name == "words":                  # the tuning clips' page: dark words on light paper, 14 px
        from vrcorrect.studies.bench.sequences import text_page

        return prepare_image(text_page(256, 256), 256, "words")
    if name == "sktext":
        from skimage import data

        return prepare_image(data.text(), 256, "sktext")
    return held_out_image(name)          # any scikit-image image by name


def parse_band(text: str) -> RobustBand | None:
    """A band from its text ("": the default; "off" or "off+cap": None, the one eye at the bank entry,
    without the light cap or with it; a band's text may end in "+nocap": that band without the cap, or
    in "+paper" or "+paper=F": that band under the paper cap, :func:`paper_cap`; "sharper=1": its sphere
    offsets point towards the eye's sharper side and stop at focus, :func:`~vrcorrect.physics.robust.oriented_band`)."""
    text = _split_paper(text)[0]
    if not text:
        return RobustBand()
    if text in ("off", "off+cap"):
        return None
    capped = not text.endswith("+nocap")
    text = text.removesuffix("+nocap")
    fields = dict(item.split("=") for item in text.split(";"))
    numbers = lambda key: tuple(float(v) for v in fields[key].split(",")) if key in fields else None  # noqa: E731
    return RobustBand(pupil_factors=numbers("pf") or (1.0,), sphere_offsets_D=numbers("so") or (-0.25, 0.0, 0.25),
                      pupil_priors=numbers("pp"), sphere_priors=numbers("sp"), light_cap=capped,
                      pull=float(fields.get("pull", 0.0)), towards_sharper=fields.get("sharper") == "1")


def _split_paper(text: str) -> tuple[str, float | None]:
    """A band's text without its "+paper[=F]" ending, and F (None: no paper cap)."""
    head, sep, tail = text.partition("+paper")
    if not sep:
        return text, None
    if tail and not tail.startswith("="):
        raise ValueError(f"{text!r}: the paper cap is '+paper' or '+paper=F'")
    return head, float(tail[1:]) if tail else 1.0


#: The paper cap's reach (sixth look): the local maximum is taken over a square this many pixels
#: from its centre, at 256 px (a letter's size and its halo).
PAPER_REACH_PX = 6


def paper_cap(target: np.ndarray, factor: float) -> np.ndarray:
    """The paper cap (sixth look): each displayed primary at most ``factor`` times the brightest target
    light within :data:`PAPER_REACH_PX` (the page's paper near a stroke), and 1.  At 1 a page cannot be
    lit above its paper, as white paper cannot be by the display.  ``target`` is ``(H, W, 3)`` or,
    inside the solver, ``(3, H, W)``."""
    from scipy.ndimage import maximum_filter

    t = np.asarray(target, np.float32)
    first = t.shape[0] == 3 and t.shape[-1] != 3
    side = t.shape[1] if first else t.shape[0]
    k = 2 * max(1, round(PAPER_REACH_PX * side / 256)) + 1
    top = maximum_filter(t, size=(1, k, k) if first else (k, k, 1), mode="nearest")
    return np.minimum(np.float32(1.0), np.float32(factor) * top).astype(np.float32)


@contextlib.contextmanager
def _paper_capped(factor: float):
    """``fast``'s light cap swapped for the paper cap while the block runs (a study, not the product)."""
    from vrcorrect.solvers import admm

    light_cap = admm.light_cap
    admm.light_cap = lambda target, floor=0.0: paper_cap(target, factor)
    try:
        yield
    finally:
        admm.light_cap = light_cap


#: The fifth look's page rule ("page-rule"): a page on white paper, on paper below WHITE_PAPER's light
#: (grey, tinted), and anything else: each its band (the text form above; "+nocap": without the light
#: cap).  Since 2026-12-02 ``vrcorrect correct`` designs by the white-rule (``--band auto``:
#: vrcorrect.physics.page.choose_band, its PAGE_BAND and WHITE_PAPER; its band since 2026-12-03 the eighth
#: look's, WHITE_RULE_2; since the ninth, WHITE_RULE_3).
PAGE_RULE = {"white": "pf=1.04;so=0,0.25;sp=5,1+nocap", "grey": "pf=1.04;so=0,0.25;sp=3,1+nocap", "other": ""}
#: The seventh look's rule ("white-rule"): the page rule's white branch alone; the default elsewhere.
WHITE_RULE = {"white": PAGE_RULE["white"], "grey": "", "other": ""}
#: The eighth look's rule ("white-rule-2", 2026-12-03): the white branch's band chosen again, for the
#: real-time twin's converged design; since then ``vrcorrect.physics.page.PAGE_BAND``.
WHITE_RULE_2 = {"white": "pf=1.2;so=0,0.5;sp=3,1+nocap", "grey": "", "other": ""}
#: The ninth look's rule ("white-rule-3", 2026-12-03, later): the eighth's band with a pull towards the
#: target of 0.005; since then ``vrcorrect.physics.page.PAGE_BAND``.
WHITE_RULE_3 = {"white": "pf=1.2;so=0,0.5;sp=3,1;pull=0.005+nocap", "grey": "", "other": ""}
RULES = {"page-rule": PAGE_RULE, "white-rule": WHITE_RULE, "white-rule-2": WHITE_RULE_2, "white-rule-3": WHITE_RULE_3}


def _rule_band(target: np.ndarray, display, rule: dict[str, str]) -> tuple[str, str]:
    """The page rule's band for a picture, and what it judged."""
    from vrcorrect.physics.page import page_verdict

    verdict = page_verdict(target, display)
    kind = "other" if not verdict.page else "white" if verdict.paper_light >= WHITE_PAPER else "grey"
    return rule[kind], f"{kind} (paper light {verdict.paper_light:.2f})"


def _band_title(text: str, band: RobustBand | None) -> str:
    if text == "page-rule":
        return (f"band page-rule: a page on paper at {WHITE_PAPER} of white or more: {PAGE_RULE['white']}; on darker "
                f"paper: {PAGE_RULE['grey']}; anything else: the default")
    if text in ("white-rule", "white-rule-2", "white-rule-3"):
        return (f"band {text}: a page on paper at {WHITE_PAPER} of white or more: {RULES[text]['white']}; anything "
                "else: the default")
    if band is None:
        paper = _split_paper(text)[1]
        return f"band {text}: the one eye at the bank entry, " + (
            "under the light cap" if text == "off+cap" else f"under the paper cap x{paper:g}" if paper is not None
            else "no light cap (--robust off)")
    paper = _split_paper(text)[1]
    return (f"band {text or 'default'}: pupil factors {band.pupil_factors} (priors {band.pupil_priors}), sphere "
            f"offsets {band.sphere_offsets_D} D (priors {band.sphere_priors})"
            + (", without the light cap" if text.endswith("+nocap") else "")
            + (f", under the paper cap x{paper:g}" if paper is not None else ""))


def guarded(shown: np.ndarray, target: np.ndarray, guards, rho: float, measure: str = "objective",
            display=None) -> tuple[np.ndarray, float]:
    """``t + b (x - t)`` with the largest ``b`` in [0, 1] that keeps every guard eye's objective (or
    ``measure``) at most ``rho`` times its value for the target shown as it is (the product's guard,
    :func:`vrcorrect.solvers.guard.guard_blend`, which ``vrcorrect correct --guard`` runs), and ``b``."""
    from vrcorrect.solvers.guard import guard_blend
    from vrcorrect.vision.visibility import ViewingLight

    done = guard_blend(shown, target, [make_problem(target, d.nominal, d.nominal_reference) for d in guards], rho,
                       measure, None if display is None else ViewingLight.of(display))
    return done.image, done.weight


def _case(display_name: str, name: str):
    key = (display_name, name)
    if key not in _cases:
        display = get_display(display_name)
        target = decode(display, choice_image(name)).astype(np.float32)
        eye = _eye["eye"]
        p = pupil_from_light(float(np.mean(target.astype(np.float64) @ luminance_weights(display))), display,
                             _eye["age"]).diameter_mm
        seen = []
        for q, s in SEEN:
            q = p if q is None else q
            exact = design_eye(eye.with_changes(sphere_D=eye.sphere_D + s), display, q, robust=False, kernels=_kernels)
            none = evaluate_seen(target, target, exact.nominal, display)[0].jod
            ceiling = None
            if (q, s) == (3.0, 0.0):
                best = solve(make_problem(target, exact.kernel, exact.reference), "fast").image
                _exact_shown[key] = best
                ceiling = evaluate_seen(best, target, exact.nominal, display)[0].jod - none
            seen.append((exact, none, ceiling))
        _cases[key] = (display, target, p, seen)
    return _cases[key]


def ceiling_of(seen) -> float:
    """The exact 3 mm design's JOD gain over none among :func:`_case`'s seen eyes (the share's 100 %)."""
    return next(c for _, _, c in seen if c is not None)


def exact_shown(display_name: str, name: str) -> np.ndarray:
    """What ``fast`` shows for the exact 3 mm design of :func:`_case`'s picture (solved there once)."""
    _case(display_name, name)
    return _exact_shown[(display_name, name)]


def seen_metrics(shown: np.ndarray, target: np.ndarray, seen, display, with_jod: bool = True) -> list:
    """What each seen eye (``seen``: :func:`_case`'s (design, none's JOD, ceiling)) sees of ``shown``
    against the ideal view of ``target``: JOD, FLIP and the objective (:func:`evaluate_seen`'s metrics)."""
    return [evaluate_seen(shown, target, exact.nominal, display, with_jod=with_jod)[0] for exact, _, _ in seen]


def seen_gains(shown: np.ndarray, target: np.ndarray, seen, display) -> list[float]:
    """Each seen eye's JOD gain over none for ``shown``."""
    return [m.jod - none for m, (_, none, _) in zip(seen_metrics(shown, target, seen, display), seen)]


def _twin_frames(solver: str) -> int | None:
    """``--solver``'s frames of the real-time twin (None: ``fast``; -1: not a solver this takes)."""
    if solver == "fast":
        return None
    head, _, n = solver.partition(":")
    return int(n) if head == "twin" and n.isdigit() and 1 <= int(n) <= 2000 else -1


def _arguments(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="robust_band_choice", description="A sweep of robust bands on the choice "
                                 "images (issue 44); see this file's docstring for the figures.")
    ap.add_argument("bands", nargs="*", help='bands to try: "" the default, "off" the one eye without the cap, '
                    '"off+cap" under the light cap, "pf=...;pp=...;so=...;sp=..." (pupil factors and priors, sphere '
                    'offsets and priors; ending in "+nocap" without the light cap, "+paper[=F]" under the paper cap), '
                    '"page-rule" or "white-rule" (a band by what the picture is); with none given, the default and the '
                    "first band")
    ap.add_argument("--image", action="append", default=[], metavar="PATH",
                    help="a picture of your own, added to the choice images (repeatable; centre-cropped to 256 px)")
    ap.add_argument("--documents", metavar="DIR", type=Path,
                    help="the real pages of tools/fetch_documents.py: their choice half is added")
    ap.add_argument("--held-out", action="store_true",
                    help="with --documents: the held-out half instead (to judge what was chosen, once)")
    ap.add_argument("--grey-paper", type=float, action="append", default=[], metavar="LIGHT",
                    help="with --documents: grey stand-ins of the white choice pages, their light times LIGHT "
                    "(0.58: the held-out scan's paper), added as NAME@LIGHT (repeatable)")
    ap.add_argument("--grey-ink", type=float, action="append", default=[], metavar="INK",
                    help="grey-ink stand-ins of every choice picture judged a page on white paper: each primary's "
                    "light L shown as INK + (1 - INK) L, the ink lifted to INK of white and the paper kept, added as "
                    "NAME^INK (repeatable; ninth look)")
    ap.add_argument("--solver", default="fast", metavar="fast|twin:N",
                    help="what designs the correction: fast (the default), or twin:N, the real-time default's CPU "
                    "twin after N frames of the still (two iterations a frame; twin:10 is what render shows, a "
                    "larger N what a still settles to)")
    ap.add_argument("--rx", metavar="RX.json", type=Path,
                    help="sweep the right eye of this prescription, at its age_years for the pupil from the light, "
                    "instead of the bench's eye (-2.00/-1.00 x 120)")
    ap.add_argument("--guard", type=float, metavar="RHO",
                    help="the objective guard (eleventh look): the correction blended towards the target, "
                    "t + b (x - t) with the largest b <= 1 that keeps the objective of the eyes with the sphere "
                    "0.5 D off either way (at the light's pupil) at most RHO times none's")
    ap.add_argument("--guard-measure", choices=GUARD_MEASURES, default="objective",
                    help="with --guard: what the guard keeps within RHO of none (thirteenth look: 'lightness', the "
                    "cube roots of each cone's light relative to white's; fourteenth look: 'visibility', the contrast "
                    "sensitivity-weighted band contrast of vrcorrect.vision.visibility)")
    ap.add_argument("--guard-pupils", action="store_true",
                    help="with --guard: the eyes at the pupils 2.5, 3, 4 and 5.5 mm are guard eyes too (all six "
                    "eyes judged)")
    ap.add_argument("--no-builtin", action="store_true",
                    help="leave out the built-in choice images (astronaut, coffee, sktext, chart, words)")
    return ap.parse_args(argv)


def main(argv: list[str]) -> int:
    args = _arguments(argv)
    try:
        bands = [(text, None if text in RULES else parse_band(text)) for text in (args.bands or BANDS)]
    except (ValueError, KeyError) as e:
        print(f"robust_band_choice: a band is 'off', '' or 'pf=...;pp=...;so=...;sp=...' ({e})", file=sys.stderr)
        return 2
    if args.rx is not None:
        from vrcorrect.apps.common import load_eye_and_age

        try:
            _, eye, age = load_eye_and_age(argparse.Namespace(rx=str(args.rx), eye="right"))
        except (VrcorrectError, OSError) as e:
            print(f"robust_band_choice: --rx {args.rx}: {e}", file=sys.stderr)
            return 2
        _eye.update(eye=eye, age=age)
        print(f"the right eye of {args.rx}: sphere {eye.sphere_D:+.2f} D, cylinder {eye.cylinder_D:+.2f} D "
              f"x {eye.axis_deg:g}" + (f", age {age:g}" if age is not None else ""), flush=True)
    frames = _twin_frames(args.solver)
    if frames is not None and frames < 0:
        print(f"robust_band_choice: --solver {args.solver!r}: 'fast' or 'twin:N' with N frames from 1 to 2000",
              file=sys.stderr)
        return 2
    images = [] if args.no_builtin else list(CHOICE_IMAGES)
    paths = list(args.image)
    if args.documents is not None:
        from fetch_documents import CHOICE, HELD_OUT as HELD_OUT_PAGES  # tools/: this script's folder

        paths += [str(args.documents / f"{n}.png") for n in (HELD_OUT_PAGES if args.held_out else CHOICE)]
        missing = [p for p in paths if not Path(p).is_file()]
        if missing:
            print(f"robust_band_choice: --documents {args.documents}: no {Path(missing[0]).name} there; fetch the "
                  f"pages first: .venv/bin/python tools/fetch_documents.py {args.documents}", file=sys.stderr)
            return 2
    elif args.held_out or args.grey_paper:
        print("robust_band_choice: --held-out and --grey-paper need --documents DIR", file=sys.stderr)
        return 2
    if args.grey_paper and args.held_out:
        print("robust_band_choice: --grey-paper makes stand-ins of choice pages only, not with --held-out",
              file=sys.stderr)
        return 2
    bad = [g for g in args.grey_paper if not 0.05 <= g <= 1.0]
    if bad:
        print(f"robust_band_choice: --grey-paper {bad[0]}: a paper light from 0.05 to 1 of white", file=sys.stderr)
        return 2
    bad = [g for g in args.grey_ink if not 0.0 < g <= 0.5]
    if bad:
        print(f"robust_band_choice: --grey-ink {bad[0]}: an ink light above 0 and at most 0.5 of white",
              file=sys.stderr)
        return 2
    for path in paths:
        name = Path(path).stem
        if name in HELD_OUT or name in images:
            print(f"robust_band_choice: --image {path}: the name {name!r} is taken (a choice or held-out image)",
                  file=sys.stderr)
            return 2
        _files[name] = path
        try:
            choice_image(name)                                                   # a bad file: one line, now
        except (VrcorrectError, OSError) as e:
            print(f"robust_band_choice: {path}: {e}", file=sys.stderr)
            return 2
        images.append(name)
    images += [f"{page}@{light:g}" for light in args.grey_paper for page in WHITE_CHOICE_PAGES]
    if args.grey_ink:
        from vrcorrect.physics.page import page_verdict

        desktop = get_display("desktop")
        verdicts = {n: page_verdict(decode(desktop, choice_image(n)).astype(np.float32), desktop)
                    for n in images if "@" not in n}
        white = [n for n, v in verdicts.items() if v.page and v.paper_light >= WHITE_PAPER]
        images += [f"{page}^{ink:g}" for ink in args.grey_ink for page in white]
    if not images:
        print("robust_band_choice: no images (--no-builtin leaves only --image and --documents)", file=sys.stderr)
        return 2
    for text, band in bands:
        t0 = time.perf_counter()
        print(_band_title(text, band) + ("" if frames is None else f"; the real-time twin after {frames} frames"),
              flush=True)
        for display_name in DISPLAYS:
            for name in images:
                display, target, p, seen = _case(display_name, name)
                case_text, case_band, judged = text, band, ""
                if text in RULES:                                                # the band by what the picture is
                    case_text, judged = _rule_band(target, display, RULES[text])
                    case_band = parse_band(case_text)
                design = design_eye(_eye["eye"], display, nearest_bank_pupil(p), band=case_band, kernels=_kernels,
                                    robust=case_band is not None)
                problem = make_design_problem(target, design)
                case_text, paper = _split_paper(case_text)
                if case_text == "off+cap" or paper is not None:                  # the one eye under the light cap,
                    problem = replace(problem, capped=True)                      # or a band under the paper cap
                elif case_text.endswith("+nocap"):                               # a band without the light cap
                    problem = replace(problem, capped=False)
                if frames is not None:                                           # the real-time twin
                    if paper is not None:
                        print("robust_band_choice: the paper cap is fast's only", file=sys.stderr)
                        return 2
                    shown = realtime_still(design, target, frames, cap=problem.capped)
                else:
                    with _paper_capped(paper) if paper is not None else contextlib.nullcontext():
                        shown = solve(problem, "fast").image
                beta, unguarded = 1.0, shown
                if args.guard is not None:                                       # the objective guard
                    shown, beta = guarded(shown, target, [e for (e, _, _), (q, o) in zip(seen, SEEN)
                                                          if o != 0.0 or (args.guard_pupils and q is not None)],
                                          args.guard, args.guard_measure, display)
                gains = seen_gains(shown, target, seen, display)
                # with the guard acting, the unguarded correction too (blend 1: the same image)
                plain = gains if beta >= 1.0 else seen_gains(unguarded, target, seen, display)
                share, plain_share = float("nan"), float("nan")
                for gain, plain_gain, (_, _, ceiling) in zip(gains, plain, seen):
                    if ceiling is not None:
                        share, plain_share = gain / ceiling, plain_gain / ceiling
                print(f"  {display_name:8s} {name:15s} light {p:.2f} mm  least {min(gains):+.3f}  share at 3 mm "
                      f"{share:4.0%}  gains " + " ".join(f"{g:+.2f}" for g in gains) + (f"  {judged}" if judged else "")
                      + (f"  blend {beta:.2f} (unguarded: least {min(plain):+.3f}, share {plain_share:4.0%})"
                         if args.guard is not None else ""),
                      flush=True)
        print(f"  ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
