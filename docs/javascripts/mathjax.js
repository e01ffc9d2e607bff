// MathJax 3 for the math of pymdownx.arithmatex (generic mode: \(...\), \[...\] in elements
// of class "arithmatex") and of the notebooks' Markdown cells (mkdocs-jupyter leaves their
// $...$ and $$...$$ as written, in elements of class "jp-RenderedMarkdown"); nothing else on
// a page is typeset, so a "$" in prose or code stays a dollar.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"], ["$", "$"]],
    displayMath: [["\\[", "\\]"], ["$$", "$$"]],
    processEscapes: true,
    processEnvironments: true,
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex|jp-RenderedMarkdown",
  },
};

// re-typeset after Material's instant navigation loads a page
document$.subscribe(() => {
  MathJax.startup.output.clearCache();
  MathJax.typesetClear();
  MathJax.texReset();
  MathJax.typesetPromise();
});
