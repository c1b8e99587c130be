"""The analysis plots (:mod:`prismstereo.analysis.plots`): what each draws, on matplotlib's Agg backend."""

import matplotlib

matplotlib.use("Agg")

import pytest  # noqa: E402
import torch  # noqa: E402

from prismstereo import thesis_setup1  # noqa: E402
from prismstereo.analysis import AnalysisError  # noqa: E402
from prismstereo.analysis.plots import new_axes, plot_curves, plot_fov_angles, plot_fov_top_view  # noqa: E402


def test_plots_draw_their_data_on_the_axes_they_are_given():
    ax = new_axes((4.0, 3.0))
    assert tuple(ax.figure.get_size_inches()) == (4.0, 3.0)
    top = plot_fov_top_view(thesis_setup1(), 1500.0, ax=ax)
    assert top is ax and len(ax.lines) >= 4 and ax.get_xlabel() and ax.get_ylabel()
    angles = plot_fov_angles(1.48, 4.7616, 25.0)
    labels = [line.get_label() for line in angles.lines]
    assert labels[:2] == ["phi_2 (Ray 1)", "phi_4 (Ray 2)"] and any(label.startswith("alpha_1") for label in labels)
    depth = torch.linspace(300.0, 900.0, 5, dtype=torch.float64)
    curves = plot_curves({"a": (depth, depth / 100), "b": (depth, depth / 50)}, styles={"a": "-", "b": "--"},
                         title="t")
    assert [line.get_label() for line in curves.lines] == ["a", "b"] and curves.get_title() == "t"
    assert curves.lines[1].get_linestyle() == "--"
    assert list(curves.lines[0].get_ydata()) == (depth / 100).tolist()
    with pytest.raises(AnalysisError, match="at least one curve"):
        plot_curves({})
