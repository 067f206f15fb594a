#include "stages/relight/relight_matrix.h"

#include "format/io/container_reader.h"
#include "stages/common/basis.h"

namespace ltb::stages {

Result<RelightMatrix> RelightMatrix::Open(const std::string& path, uint64_t mem_limit, int jobs,
                                          const Progress& progress, nlohmann::json* report) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader reader, io::ContainerReader::Open(path));
  RelightMatrix m;
  m.path_ = path;
  m.jobs_ = jobs;
  m.progress_ = progress;
  LTB_ASSIGN_OR_RETURN(m.basis_, LightingBasis::FromMetadata(reader.metadata(), path));
  const bool is_cpca = CpcaModel::IsCpca(reader.metadata());
  const bool streaming = !is_cpca && reader.metadata().matrix().layout == format::Layout::kRows;
  m.rows_ = reader.metadata().matrix().rows;
  nlohmann::json unused;
  if (report == nullptr) report = &unused;
  if (is_cpca) {  // clustered PCA: project the lighting per cluster, blend per row
    LTB_ASSIGN_OR_RETURN(CpcaRelighter r, CpcaRelighter::Load(path, mem_limit));
    m.cpca_ = std::move(r);
    m.rows_ = m.cpca_->rows();
    (*report)["cpca"] = {{"clusters", m.cpca_->model().clusters()}, {"basis", m.cpca_->model().basis()}};
    (*report)["matrix_bytes_in_memory"] = m.cpca_->bytes();
    if (auto img = m.cpca_->model().image()) {
      m.width_ = img->first;
      m.height_ = img->second;
    }
  } else if (!streaming) {
    LTB_ASSIGN_OR_RETURN(Relighter r, Relighter::Load(path, mem_limit, progress, jobs));
    m.relighter_ = std::move(r);
    (*report)["nonzeros"] = m.relighter_->nonzeros();
    (*report)["matrix_bytes_in_memory"] = m.relighter_->bytes();
    m.width_ = m.relighter_->image_width();
    m.height_ = m.relighter_->image_height();
  } else if (auto img = ReadImageRows(reader.metadata())) {
    m.width_ = img->width;
    m.height_ = img->height;
  }
  LTB_ASSIGN_OR_RETURN(m.mask_, ReadRowMask(reader));
  return m;
}

const std::vector<double>& RelightMatrix::column_norms() const {
  static const std::vector<double> kNoNorms;
  return relighter_ ? relighter_->column_norms() : kNoNorms;
}

Status RelightMatrix::Relight(const LightTerms& terms, std::vector<float>* image) {
  image->resize(rows_ * 3);
  if (relighter_) {
    relighter_->Relight(terms, image->data());
    return Status::Ok();
  }
  if (cpca_) {
    cpca_->RelightTerms(terms.column, terms.rgb, image->data());
    return Status::Ok();
  }
  std::vector<float> dense(6 * basis_.cube_res() * basis_.cube_res() * 3, 0.0f);
  for (size_t k = 0; k < terms.column.size(); ++k)
    for (int c = 0; c < 3; ++c) dense[terms.column[k] * 3 + c] = terms.rgb[k * 3 + c];
  return RelightDense(dense, image);
}

Status RelightMatrix::RelightDense(const std::vector<float>& lighting, std::vector<float>* image) {
  if (relighter_) {
    LightTerms every;
    LTB_RETURN_IF_ERROR(
        basis_.SelectTerms(lighting.data(), lighting.size() / 3, Weighting::kNone, column_norms(), &every));
    return Relight(every, image);
  }
  if (cpca_) {
    image->resize(rows_ * 3);
    cpca_->Relight(lighting.data(), image->data());
    return Status::Ok();
  }
  LTB_ASSIGN_OR_RETURN(*image, RelightStreaming(path_, lighting.data(), jobs_, progress_));
  return Status::Ok();
}

}  // namespace ltb::stages
